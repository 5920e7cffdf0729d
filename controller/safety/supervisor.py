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
from bisect import bisect_left

import numpy as np
from fluidsense.common.faults import Fault, FaultKind
from fluidsense.common.samples import SampleBlock
from fluidsense.common.units import KPA
from fluidsense.controller.config import Profile, Supervision


class _HeldMeans:
    """Block means (t, p_act) of the last 1.5 s while held, with running sums, so that the
    leak check's three half-second least-squares slopes cost a few float operations per
    block instead of a dozen numpy calls (it runs on every block of a hold; it was about a
    fifth of the virtual-time cell's cost, ``python -m lab bench sim``).

    The sums are of t - t_ref and p - p_ref and start again from the kept means whenever
    the dropped ones pile up: a window's sums are differences of two running sums, which
    stay exact to a few ulps only while the running sums stay small (an hour's hold would
    otherwise cancel sxx to nothing)."""

    SPAN_S = 1.5
    _REBASE = 256  # dropped means kept in the lists before the sums start again

    def __init__(self) -> None:
        self._reset()

    def clear(self) -> None:
        if self.t:  # called on every block that is not a hold: nothing to drop between holds
            self._reset()

    def _reset(self) -> None:
        self.t: list[float] = []
        self.p: list[float] = []
        self.lo = 0
        self._t_ref = self._p_ref = 0.0
        # running sums of 1, t, p, t^2, t*p, p^2 (of t - t_ref, p - p_ref) before each mean
        self._sums: list[tuple[float, float, float, float, float]] = [(0.0, 0.0, 0.0, 0.0, 0.0)]

    def append(self, t: float, p: float) -> None:
        if not self.t:
            self._t_ref, self._p_ref = t, p
        self.t.append(t)
        self.p.append(p)
        self._add(t, p)
        while len(self.t) - self.lo > 1 and t - self.t[self.lo] > self.SPAN_S:
            self.lo += 1
        if self.lo >= self._REBASE:
            self._rebase()

    def _add(self, t: float, p: float) -> None:
        x, y = t - self._t_ref, p - self._p_ref
        st, sp, stt, stp, spp = self._sums[-1]
        self._sums.append((st + x, sp + y, stt + x * x, stp + x * y, spp + y * y))

    def _rebase(self) -> None:
        self.t, self.p, self.lo = self.t[self.lo:], self.p[self.lo:], 0
        self._t_ref, self._p_ref = self.t[0], self.p[0]
        self._sums = [(0.0, 0.0, 0.0, 0.0, 0.0)]
        for t, p in zip(self.t, self.p):
            self._add(t, p)

    def newest(self) -> float:
        return self.t[-1]

    def index(self, t: float) -> int:
        """The first kept mean at or after ``t``."""
        return bisect_left(self.t, t, self.lo)

    def slope(self, a: int, b: int) -> tuple[float, float] | None:
        """Least-squares slope (Pa/s) of means a..b-1 and its standard error; None for
        fewer than four means."""
        n = b - a
        if n < 4:
            return None
        t0, p0, tt0, tp0, pp0 = self._sums[a]
        t1, p1, tt1, tp1, pp1 = self._sums[b]
        st, sp, stt, stp, spp = t1 - t0, p1 - p0, tt1 - tt0, tp1 - tp0, pp1 - pp0
        sxx = stt - st * st / n
        sxy = stp - st * sp / n
        syy = spp - sp * sp / n
        slope = sxy / sxx
        rss = max(syy - slope * sxy, 0.0)  # rounding can take an exact line's residual below 0
        return slope, math.sqrt(rss / (n - 2) / sxx)


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
        self._plans: dict[tuple[str, ...], list[tuple[int, str, float, float, bool]]] = {}
        self._hold = _HeldMeans()  # (t, p_act) block means while held after the windows
        self._hold_t0: float | None = None

    def check(self, block: SampleBlock, holding: bool = False, arm_stopped: bool = False) -> Fault | None:
        """``holding``: the actuator is inflated and its windows are done (equilibrium)."""
        if arm_stopped:
            return Fault(FaultKind.PROTECTIVE_STOP, None, block.t_end, "the arm is protective-stopped")
        # this runs on every block, which holds a few samples per channel: plain floats
        # are several times cheaper than numpy's reductions at that size, and the usual
        # block (every reading good, the newest one new) takes no call per channel
        columns = block.values.T.tolist()
        plan = self._plans.get(block.channels)
        if plan is None:
            plan = self._plans[block.channels] = self._plan(block.channels)
        t_end, min_pa, max_pa = block.t_end, self.min_pa, self.max_pa
        for j, ch, rail_lo, rail_hi, stuck_check in plan:
            v = columns[j]
            # a NaN or an infinity makes the sum non-finite (min and max of a NaN are not
            # to be trusted); which rule broke, and where, only for the rare block that breaks one
            v_min, v_max = min(v), max(v)
            if not (math.isfinite(sum(v)) and rail_lo < v_min and v_max < rail_hi
                    and min_pa <= v_min and v_max <= max_pa):
                fault = self._broken_rule(ch, block.t, block.values[:, j])
                if fault is not None:
                    return fault
            if not stuck_check:
                continue
            if len(v) > 1 and v[-1] != v[-2]:
                self._last[ch] = (v[-1], t_end)  # a live sensor's usual block: its last reading is new
            else:
                fault = self._check_stuck(ch, block.t, v)
                if fault is not None:
                    return fault
        if "p_act" in block.channels:
            return self._check_leak(block, columns[block.channels.index("p_act")], holding)
        return None

    def _plan(self, channels: tuple[str, ...]) -> list[tuple[int, str, float, float, bool]]:
        """The pressure channels of a block layout: (column, name, rails, stuck check)."""
        return [(j, ch, *self.rails.get(ch, (-math.inf, math.inf)), self.stuck_check.get(ch, True))
                for j, ch in enumerate(channels) if ch.startswith("p_")]

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
        """A block whose last reading repeats the one before (``check`` takes the usual
        block, whose last reading is new, without this call): since when unchanged."""
        value, since = self._last.get(ch, (math.nan, float(t[0])))
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
        held = self._hold
        held.append(sum(t) / len(t), sum(p) / len(p))
        newest = held.newest()
        if newest - self._hold_t0 < 1.5:
            return None
        sign = 1.0 if self.vacuum else -1.0  # towards atmosphere
        # the three half-second windows, newest first: a hold without a leak fails the newest
        # and the older two are never fitted (any window that fails decides)
        slopes, limits = [], []
        for k in (2, 1, 0):
            fit = held.slope(held.index(newest - 1.5 + 0.5 * k), held.index(newest - 1.0 + 0.5 * k + 1e-9))
            if fit is None:
                return None
            slope, se = fit
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
