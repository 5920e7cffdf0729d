"""Lumped isothermal gas network (paper, Methods, eq. 3-9).

State: the amount of gas in each volume, stored as ``m = n*R*T0`` (Pa*m^3), so that
``p_abs * v = m`` for an isothermal ideal gas at the reference temperature. Volumes are
joined by laminar links ``q = (p_a - p_b) / r`` (standard m^3/s, eq. 3), enabled or not by
valve states; the amount moved is ``dm/dt = p_std * q`` (eq. 8-9, with the density of
air at standard conditions).

Actuator volumes are piecewise-linear laws ``v(p_gauge)``: a free P-V law plus a scene
contact law fold into one table, and ``p*v(p) = m`` is then solved exactly segment by
segment (a quadratic), so the pressure of every volume follows from the state without
iteration.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from fluidsense.common.units import P_ATM

REGULATOR = -1  # node index of the regulator output (a pressure source)
ATMOSPHERE = -2  # node index of the atmosphere
_MIN_VOLUME = 1e-12  # m^3; a law is never allowed to reach zero volume


class VolumeLaw:
    """Piecewise-linear volume ``v(p_gauge)`` with linear extrapolation at both ends.

    Breakpoints must have increasing pressure and non-decreasing volume (a cavity never
    shrinks when its pressure rises), which makes ``m(p) = p_abs * v`` strictly
    increasing and therefore invertible.
    """

    __slots__ = ("p_gauge", "volume", "p_atm", "_m", "_slopes", "_pg_list", "_m_list", "_v_list", "_stop_stiffness")

    def __init__(self, p_gauge: Sequence[float], volume: Sequence[float], p_atm: float = P_ATM):
        pg = np.asarray(p_gauge, dtype=float)
        vol = np.asarray(volume, dtype=float)
        if pg.ndim != 1 or pg.shape != vol.shape or len(pg) < 1:
            raise ValueError("volume law needs matching 1-D pressure and volume breakpoints")
        if len(pg) > 1 and (np.any(np.diff(pg) <= 0) or np.any(np.diff(vol) < 0)):
            raise ValueError("volume law breakpoints must rise in pressure and not fall in volume")
        if np.any(vol <= 0):
            raise ValueError("volume law has a non-positive volume")
        self.p_gauge = pg
        self.volume = vol
        self.p_atm = float(p_atm)
        if len(pg) == 1:
            self._slopes = np.zeros(1)
        else:
            self._slopes = np.diff(vol) / np.diff(pg)
        self._m = (pg + p_atm) * vol
        self._pg_list = pg.tolist()
        self._m_list = self._m.tolist()
        self._v_list = vol.tolist()
        positive = self._slopes[self._slopes > 0]
        self._stop_stiffness = 1e3 / float(positive.max()) if len(positive) else 1e15

    @classmethod
    def constant(cls, volume: float, p_atm: float = P_ATM) -> VolumeLaw:
        return cls([0.0], [volume], p_atm)

    def _segment(self, idx):
        n = len(self._slopes)
        return np.clip(idx - 1, 0, n - 1)

    def volume_at(self, p_gauge):
        """Volume (m^3) at gauge pressure (Pa); scalars or arrays."""
        pg = np.asarray(p_gauge, dtype=float)
        j = self._segment(np.searchsorted(self.p_gauge, pg, side="right"))
        v = self.volume[j] + self._slopes[j] * (pg - self.p_gauge[j])
        return np.maximum(v, _MIN_VOLUME)

    def compliance_at(self, p_gauge):
        """dv/dp (m^3/Pa) at gauge pressure."""
        pg = np.asarray(p_gauge, dtype=float)
        return self._slopes[self._segment(np.searchsorted(self.p_gauge, pg, side="right"))]

    def pressure_abs(self, m: float) -> float:
        """Absolute pressure (Pa) of gas amount ``m`` (Pa*m^3) in this volume. Scalar fast path."""
        j = min(max(bisect_right(self._m_list, m) - 1, 0), len(self._slopes) - 1)
        s = self._slopes[j]
        pg_j = self._pg_list[j]
        v_j = self.volume[j]
        # v(pg) = a + s*pg with a = v_j - s*pg_j ;  (P_atm + pg) * (a + s*pg) = m
        a = v_j - s * pg_j
        b = a + s * self.p_atm
        c = self.p_atm * a - m
        if s == 0.0:
            pg = -c / b
        else:
            # root continuous as s -> 0; written to avoid cancellation
            pg = -2.0 * c / (b + math.sqrt(max(b * b - 4.0 * s * c, 0.0)))
        return pg + self.p_atm

    def pressure_abs_array(self, m: np.ndarray) -> np.ndarray:
        m = np.asarray(m, dtype=float)
        j = self._segment(np.searchsorted(self._m, m, side="right"))
        s = self._slopes[j]
        a = self.volume[j] - s * self.p_gauge[j]
        b = a + s * self.p_atm
        c = self.p_atm * a - m
        disc = np.sqrt(np.maximum(b * b - 4.0 * s * c, 0.0))
        pg = -2.0 * c / (b + disc)
        return pg + self.p_atm

    def pressure_for_volume(self, v: float) -> float:
        """Gauge pressure the actuator's structure holds at volume ``v`` (the inverse law).

        A flat segment (a rigid stop: the volume cannot grow) is inverted as a spring a
        thousand times stiffer than the stiffest free segment, which is what a stop is on
        the actuator's time scales and keeps the inverse a function.
        """
        vols = self.volume
        j = min(max(bisect_right(self._v_list, v) - 1, 0), len(self._slopes) - 1)
        s = self._slopes[j]
        if s <= 0.0:
            return self._pg_list[j] + (v - vols[j]) * self._stop_stiffness
        return self._pg_list[j] + (v - vols[j]) / s

    def amount_at(self, p_gauge: float) -> float:
        """Gas amount m (Pa*m^3) at gauge pressure."""
        return float((p_gauge + self.p_atm) * self.volume_at(p_gauge))


@dataclass(frozen=True)
class Pipe:
    """A laminar path between two nodes (node index, or REGULATOR / ATMOSPHERE)."""

    a: int
    b: int
    resistance: float  # Pa*s/m^3
    valve: str | None = None  # enabled only when this valve ...
    when_open: bool = True  # ... is in this logical state
    name: str = ""

    def enabled(self, valves: dict[str, bool]) -> bool:
        return self.valve is None or valves[self.valve] == self.when_open


@dataclass(frozen=True)
class FlowSource:
    """A mass flow controller feeding a node; only flows while its valve path is open."""

    node: int
    valve: str | None = None
    when_open: bool = True


class Network:
    """Nodes (volumes with laws), links and sources; builds the ODE right-hand side."""

    def __init__(self, names: Sequence[str], laws: Sequence[VolumeLaw], links: Sequence[Pipe],
                 p_atm: float = P_ATM, p_std: float = P_ATM, flow_sources: Sequence[FlowSource] = (),
                 dampers: dict[int, float] | None = None):
        if len(names) != len(laws):
            raise ValueError("one volume law per node")
        # node -> damping (Pa*s/m^3): that node's volume is a state of its own that follows
        # the law through a dashpot (Kelvin-Voigt), see ``rhs_factory``
        self.dampers = {int(i): float(b) for i, b in (dampers or {}).items()}
        if any(not 0 <= i < len(names) or not b > 0 for i, b in self.dampers.items()):
            raise ValueError("dampers need a known node and a positive damping")
        self.dynamic = sorted(self.dampers)
        self.names = list(names)
        self.index = {n: i for i, n in enumerate(self.names)}
        self.laws = list(laws)
        self.links = list(links)
        self.flow_sources = list(flow_sources)
        self.p_atm = p_atm
        self.p_std = p_std
        for link in self.links:
            for end in (link.a, link.b):
                if end not in (REGULATOR, ATMOSPHERE) and not 0 <= end < len(self.names):
                    raise ValueError(f"link {link.name!r} refers to unknown node {end}")
            if not link.resistance > 0:
                raise ValueError(f"link {link.name!r} needs a positive resistance")

    @property
    def n_nodes(self) -> int:
        return len(self.names)

    @property
    def n_state(self) -> int:
        """Gas amounts, the regulator output, then the volume of each damped node."""
        return self.n_nodes + 1 + len(self.dynamic)

    def volume_slot(self, node: int) -> int | None:
        """Index in the state vector of a damped node's volume (None: quasi-static node)."""
        return self.n_nodes + 1 + self.dynamic.index(node) if node in self.dampers else None

    def rhs_factory(self, valves: dict[str, bool], laws: Sequence[VolumeLaw],
                    regulator_target_abs: float, regulator_tau: float,
                    flow_of_t: Callable[[float], float] | None) -> Callable:
        """Right-hand side for one segment with fixed valve states.

        State vector: ``[m_0 .. m_{n-1}, p_regulator_abs, v_d ...]``. A quasi-static node's
        pressure follows from its law; a damped node's volume ``v`` is a state, its
        pressure is ``m / v``, and the structure yields at the rate the pressure exceeds
        what the structure holds at that volume: ``b dv/dt = p - p_law(v)``. In a free
        segment of compliance ``c`` this is a first-order lag of time constant ``b c``.
        """
        active = [(lk.a, lk.b, 1.0 / lk.resistance) for lk in self.links if lk.enabled(valves)]
        sources = [fs.node for fs in self.flow_sources if fs.valve is None or valves[fs.valve] == fs.when_open]
        n = self.n_nodes
        p_std = self.p_std
        p_atm = self.p_atm
        laws = list(laws)
        tau = max(regulator_tau, 1e-6)

        dyn = [(i, n + 1 + k, self.dampers[i]) for k, i in enumerate(self.dynamic)]
        n_state = self.n_state

        def rhs(t: float, y: np.ndarray) -> np.ndarray:
            p = [laws[i].pressure_abs(y[i]) for i in range(n)]
            dy = np.zeros(n_state)
            for i, slot, b in dyn:
                v = max(y[slot], _MIN_VOLUME)
                p[i] = y[i] / v
                dy[slot] = (p[i] - p_atm - laws[i].pressure_for_volume(v)) / b
            p_reg = y[n]
            for a, b, g in active:
                pa_ = p_reg if a == REGULATOR else (p_atm if a == ATMOSPHERE else p[a])
                pb_ = p_reg if b == REGULATOR else (p_atm if b == ATMOSPHERE else p[b])
                dm = p_std * (pa_ - pb_) * g
                if a >= 0:
                    dy[a] -= dm
                if b >= 0:
                    dy[b] += dm
            if sources and flow_of_t is not None:
                q = flow_of_t(t)
                for node in sources:
                    dy[node] += p_std * q
            dy[n] = (regulator_target_abs - p_reg) / tau
            return dy

        return rhs

    def link_flows(self, valves: dict[str, bool], p_abs: np.ndarray, p_reg: np.ndarray,
                   names: Sequence[str]) -> dict[str, np.ndarray]:
        """Standard volumetric flow (m^3/s, positive a->b) through named links."""
        out: dict[str, np.ndarray] = {}
        for link in self.links:
            if link.name not in names:
                continue
            if not link.enabled(valves):
                out[link.name] = out.get(link.name, np.zeros(p_reg.shape))
                continue
            pa_ = p_reg if link.a == REGULATOR else (np.full_like(p_reg, self.p_atm) if link.a == ATMOSPHERE else p_abs[link.a])
            pb_ = p_reg if link.b == REGULATOR else (np.full_like(p_reg, self.p_atm) if link.b == ATMOSPHERE else p_abs[link.b])
            out[link.name] = out.get(link.name, 0.0) + (pa_ - pb_) / link.resistance
        return out
