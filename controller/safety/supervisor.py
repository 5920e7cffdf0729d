"""Safety supervisor: checks every block before the sequencer sees it (docs/safety.md).

A finding is a ``Fault``; the controller answers any fault with the safe state (actuator
vented, tank isolated, arm stopped), publishes it and latches it until ``reset``.

Checks, per block: a pressure channel reading NaN, on its sensor's rail (out of range),
frozen (stuck: not one changed reading for ``stuck_s``), beyond the profile's limits
(positive and vacuum); a leak while the actuator is held (a sustained decay towards
atmosphere after the measurement windows: three consecutive half-second slopes beyond
``leak_kpa_per_s`` and beyond three standard errors of each slope, so that neither a
single step such as an object slipping nor a noisy sensor is a leak); the arm
protective-stopped. The controller adds no data, link loss and loop overrun, which are
about blocks not arriving rather than their content.
"""

from __future__ import annotations

import math

import numpy as np
from fluidsense.common.faults import Fault, FaultKind
from fluidsense.common.samples import SampleBlock
from fluidsense.common.units import KPA
from fluidsense.controller.config import Profile, Supervision


def _slope(t: np.ndarray, p: np.ndarray) -> tuple[float, float]:
    """Least-squares slope and its standard error."""
    tc = t - t.mean()
    sxx = float(tc @ tc)
    slope = float(tc @ (p - p.mean())) / sxx
    resid = p - p.mean() - slope * tc
    return slope, float(np.sqrt((resid @ resid) / (len(t) - 2) / sxx))


class _HeldMeans:
    """Block means (t, p_act) of the last 1.5 s while held, in arrays that grow in place:
    the leak check looks at them on every block of a hold."""

    SPAN_S = 1.5

    def __init__(self, capacity: int = 512):
        self.t, self.p = np.empty(capacity), np.empty(capacity)
        self.lo = self.hi = 0

    def clear(self) -> None:
        self.lo = self.hi = 0

    def append(self, t: float, p: float) -> None:
        if self.hi == len(self.t):
            n = self.hi - self.lo
            if 2 * n > len(self.t):
                self.t, self.p = np.resize(self.t, 2 * len(self.t)), np.resize(self.p, 2 * len(self.p))
            self.t[:n], self.p[:n] = self.t[self.lo:self.hi].copy(), self.p[self.lo:self.hi].copy()
            self.lo, self.hi = 0, n
        self.t[self.hi], self.p[self.hi] = t, p
        self.hi += 1
        while self.hi - self.lo > 1 and t - self.t[self.lo] > self.SPAN_S:
            self.lo += 1

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        return self.t[self.lo:self.hi], self.p[self.lo:self.hi]


class Supervisor:
    def __init__(self, profile: Profile, cfg: Supervision | None = None):
        self.cfg = cfg or Supervision()
        self.max_pa = profile.limits.max_pa
        self.min_pa = profile.limits.min_pa
        # a reading on a sensor's rail means it is saturated: the true value is unknown
        self.rails = {
            "p_act": (profile.sensor.range_kpa[0] * KPA, profile.sensor.range_kpa[1] * KPA),
            "p_tank": (profile.tank_sensor.range_kpa[0] * KPA, profile.tank_sensor.range_kpa[1] * KPA),
        }
        # a sensor declared noise-free and unquantised cannot be told from a stuck one
        self.stuck_check = {
            "p_act": profile.sensor.noise_sd_kpa > 0 or profile.sensor.quantum_kpa > 0,
            "p_tank": profile.tank_sensor.noise_sd_kpa > 0 or profile.tank_sensor.quantum_kpa > 0,
        }
        self.vacuum = profile.sequence.p0_kpa < 0
        self._last: dict[str, tuple[float, float]] = {}  # channel -> (value, since when unchanged)
        self._hold = _HeldMeans()  # (t, p_act) block means while held after the windows
        self._hold_t0: float | None = None

    def check(self, block: SampleBlock, holding: bool = False, arm_stopped: bool = False) -> Fault | None:
        """``holding``: the actuator is inflated and its windows are done (equilibrium)."""
        if arm_stopped:
            return Fault(FaultKind.PROTECTIVE_STOP, None, block.t_end, "the arm is protective-stopped")
        # this runs on every block, which holds a few samples per channel: plain floats
        # are several times cheaper than numpy's reductions at that size
        columns = block.values.T.tolist()
        for j, ch in enumerate(block.channels):
            if not ch.startswith("p_"):
                continue
            fault = self._check_channel(ch, block.t, block.values[:, j], columns[j])
            if fault is not None:
                return fault
        if "p_act" in block.channels:
            return self._check_leak(block, columns[block.channels.index("p_act")], holding)
        return None

    def _plainly_good(self, ch: str, v: list[float]) -> bool:
        """Every reading finite, off the rails and within the limits (a NaN or an infinity
        makes the sum non-finite; min and max are taken only of finite readings);
        ``_broken_rule`` finds which rule is broken, and where, only for the rare block
        that breaks one."""
        if not math.isfinite(sum(v)):
            return False
        v_min, v_max = min(v), max(v)
        rail_lo, rail_hi = self.rails.get(ch, (-np.inf, np.inf))
        return rail_lo < v_min and v_max < rail_hi and self.min_pa <= v_min and v_max <= self.max_pa

    def _check_channel(self, ch: str, t: np.ndarray, v: np.ndarray, column: list[float]) -> Fault | None:
        fault = None if self._plainly_good(ch, column) else self._broken_rule(ch, t, v)
        if fault is None and self.stuck_check.get(ch, True):
            return self._check_stuck(ch, t, column)
        return fault

    def _broken_rule(self, ch: str, t: np.ndarray, v: np.ndarray) -> Fault | None:
        """Which rule a reading breaks first: NaN, a rail, the limits."""
        bad = ~np.isfinite(v)
        if bad.any():
            k = int(np.argmax(bad))
            return Fault(FaultKind.SENSOR_NAN, ch, float(t[k]), f"{ch} reads NaN")
        lo, hi = self.rails.get(ch, (-np.inf, np.inf))
        rail = (v <= lo) | (v >= hi)
        if rail.any():
            k = int(np.argmax(rail))
            return Fault(FaultKind.SENSOR_RANGE, ch, float(t[k]), f"{ch} at its range limit ({v[k] / KPA:.2f} kPa)")
        over = v > self.max_pa
        if over.any():
            k = int(np.argmax(over))
            return Fault(FaultKind.OVER_PRESSURE, ch, float(t[k]),
                         f"{ch} {v[k] / KPA:.2f} kPa above the limit {self.max_pa / KPA:.2f} kPa")
        under = v < self.min_pa
        if under.any():
            k = int(np.argmax(under))
            return Fault(FaultKind.UNDER_PRESSURE, ch, float(t[k]),
                         f"{ch} {v[k] / KPA:.2f} kPa below the limit {self.min_pa / KPA:.2f} kPa")
        return None

    def _check_stuck(self, ch: str, t: np.ndarray, v: list[float]) -> Fault | None:
        value, since = self._last.get(ch, (math.nan, float(t[0])))
        if len(v) > 1 and v[-1] != v[-2]:
            since = float(t[-1])  # a live sensor's usual block: its last reading is new
        else:
            changed = [i for i, (a, b) in enumerate(zip([value, *v[:-1]], v)) if a != b]
            if changed:
                since = float(t[changed[-1]])
        self._last[ch] = (v[-1], since)
        if float(t[-1]) - since >= self.cfg.stuck_s:
            return Fault(FaultKind.SENSOR_STUCK, ch, since + self.cfg.stuck_s,
                         f"{ch} has read {v[-1] / KPA:.3f} kPa for {float(t[-1]) - since:.2f} s")
        return None

    def _check_leak(self, block: SampleBlock, p: list[float], holding: bool) -> Fault | None:
        if not holding:
            self._hold.clear()
            self._hold_t0 = None
            return None
        t = block.t.tolist()
        if self._hold_t0 is None:
            self._hold_t0 = t[0]
        # keep 1.5 s, in block means (enough for three half-second slopes)
        self._hold.append(sum(t) / len(t), sum(p) / len(p))
        tt, pp = self._hold.arrays()
        if tt[-1] - self._hold_t0 < 1.5:
            return None
        sign = 1.0 if self.vacuum else -1.0  # towards atmosphere
        # the three half-second windows, newest first: a hold without a leak fails the newest
        # and the older two are never fitted (any window that fails decides)
        bounds = np.searchsorted(tt, [tt[-1] - 1.5 + 0.5 * k for k in range(3)]
                                 + [tt[-1] - 1.0 + 0.5 * k + 1e-9 for k in range(3)])
        slopes, limits = [], []
        for k in (2, 1, 0):
            a, b = bounds[k], bounds[3 + k]
            if b - a < 4:
                return None
            slope, se = _slope(tt[a:b], pp[a:b])
            # a slope within noise of zero is no evidence of a leak, however steep the
            # noise makes it look: the limit rises to three standard errors
            limit = max(self.cfg.leak_kpa_per_s, 3.0 * se / KPA)
            if not slope * sign / KPA > limit:
                return None
            slopes.append(slope * sign / KPA)
            limits.append(limit)
        rate, limit = min(slopes), max(limits)
        return Fault(FaultKind.LEAK, "p_act", float(block.t_end),
                     f"held pressure falls {rate:.2f} kPa/s towards atmosphere (limit {limit:.2f} kPa/s)")
