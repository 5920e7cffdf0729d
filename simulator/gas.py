"""Lumped gas network (paper, Methods, eq. 3-9), isothermal or with wall heat exchange.

State: per volume ``E = p_abs * v`` (Pa*m^3). For an isothermal volume E is the amount of
gas ``m = n*R*T0`` at the reference temperature T0 (eq. 4-5). A volume with a wall time
constant (``thermal``) also carries its amount m in a slot of its own; its temperature is
``T = T0 * E / m`` and E follows the energy balance of an open ideal-gas volume
(``elements`` explains the wall term): ``dE/dt = H - (gamma - 1) p dv/dt`` with
``H = gamma * (sum of inflows at their upstream temperature - outflows at its own)
+ m (1 - T/T0) / tau``. Volumes are joined by laminar links ``q = (p_a - p_b) / r``
(standard m^3/s, eq. 3; the amount moved is ``p_std * q``, eq. 8-9), by ISO 6358 valves or
by hoses (``elements``), enabled or not by valve states.

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

from .elements import GAMMA, hose_amount_flow, iso6358_amount_flow

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
        # np.minimum/np.maximum, not np.clip: the same integers at a third of the call's
        # cost, which counts on the virtual-time cell's every chunk
        return np.minimum(np.maximum(idx - 1, 0), len(self._slopes) - 1)

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

    def volume_compliance(self, p_gauge: float) -> tuple[float, float]:
        """(volume, dv/dp) at a gauge pressure: the scalar fast path of the two above."""
        j = min(max(bisect_right(self._pg_list, p_gauge) - 1, 0), len(self._slopes) - 1)
        s = float(self._slopes[j])
        return max(self._v_list[j] + s * (p_gauge - self._pg_list[j]), _MIN_VOLUME), s

    def amount_at(self, p_gauge: float) -> float:
        """Gas amount m (Pa*m^3) at gauge pressure."""
        return float((p_gauge + self.p_atm) * self.volume_at(p_gauge))


@dataclass(frozen=True)
class Pipe:
    """A path between two nodes (node index, or REGULATOR / ATMOSPHERE): laminar with
    ``resistance``, or an ``element``: ``("iso6358", C in m^3/(s*Pa), b)`` or
    ``("hose", bore_m, length_m)``."""

    a: int
    b: int
    resistance: float  # Pa*s/m^3 (laminar links)
    valve: str | None = None  # enabled only when this valve ...
    when_open: bool = True  # ... is in this logical state
    name: str = ""
    element: tuple | None = None

    def enabled(self, valves: dict[str, bool]) -> bool:
        return self.valve is None or valves[self.valve] == self.when_open

    def amount_flow(self, p_a: float, p_b: float, th_a: float, th_b: float, p_std: float) -> float:
        """Amount (m units per second) moved a -> b at these pressures and temperatures (over T0)."""
        el = self.element
        if el is None:
            return p_std * (p_a - p_b) / self.resistance
        if el[0] == "iso6358":
            return iso6358_amount_flow(el[1], el[2], p_a, p_b, th_a, th_b)
        return hose_amount_flow(el[1], el[2], p_a, p_b, th_a if p_a >= p_b else th_b)


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
                 dampers: dict[int, float] | None = None, thermal: dict[int, float] | None = None):
        if len(names) != len(laws):
            raise ValueError("one volume law per node")
        # node -> damping (Pa*s/m^3): that node's volume is a state of its own that follows
        # the law through a dashpot (Kelvin-Voigt), see ``rhs_factory``
        self.dampers = {int(i): float(b) for i, b in (dampers or {}).items()}
        if any(not 0 <= i < len(names) or not b > 0 for i, b in self.dampers.items()):
            raise ValueError("dampers need a known node and a positive damping")
        self.dynamic = sorted(self.dampers)
        # node -> wall time constant (s); the other nodes are isothermal
        self.thermal = {int(i): float(t) for i, t in (thermal or {}).items()}
        if any(not 0 <= i < len(names) or not t > 0 for i, t in self.thermal.items()):
            raise ValueError("wall time constants need a known node and a positive value")
        self.heated = sorted(self.thermal)
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
            if link.element is None and not link.resistance > 0:
                raise ValueError(f"link {link.name!r} needs a positive resistance")
            if link.element is not None and (link.element[0] not in ("iso6358", "hose") or not link.element[1] > 0):
                raise ValueError(f"link {link.name!r}: unknown element {link.element!r}")

    @property
    def n_nodes(self) -> int:
        return len(self.names)

    @property
    def n_state(self) -> int:
        """E = p*v of every node, the regulator output, the volume of each damped node,
        then the amount of each node with a wall time constant."""
        return self.n_nodes + 1 + len(self.dynamic) + len(self.heated)

    def volume_slot(self, node: int) -> int | None:
        """Index in the state vector of a damped node's volume (None: quasi-static node)."""
        return self.n_nodes + 1 + self.dynamic.index(node) if node in self.dampers else None

    def amount_slot(self, node: int) -> int | None:
        """Index of a heat-exchanging node's amount (None: isothermal, its E is its amount)."""
        return self.n_nodes + 1 + len(self.dynamic) + self.heated.index(node) if node in self.thermal else None

    def theta(self, y: np.ndarray) -> np.ndarray:
        """Temperature over T0 of every node for state(s) ``y`` (1 for isothermal nodes)."""
        y = np.asarray(y, dtype=float)
        out = np.ones((self.n_nodes,) + y.shape[1:])
        for i in self.heated:
            out[i] = y[i] / np.maximum(y[self.amount_slot(i)], 1e-300)
        return out

    def rhs_factory(self, valves: dict[str, bool], laws: Sequence[VolumeLaw],
                    regulator_target_abs: float, regulator_tau: float,
                    flow_of_t: Callable[[float], float] | None) -> Callable:
        """Right-hand side for one segment with fixed valve states.

        State vector: ``[E_0 .. E_{n-1}, p_regulator_abs, v_d ..., m_h ...]``. A quasi-static
        node's pressure follows from its law (``p * v(p) = E``); a damped node's volume
        ``v`` is a state, its pressure is ``E / v``, and the structure yields at the rate
        the pressure exceeds what the structure holds at that volume:
        ``b dv/dt = p - p_law(v)``. In a free segment of compliance ``c`` this is a
        first-order lag of time constant ``b c``. A heat-exchanging quasi-static node's
        ``p dv/dt`` work is folded in exactly: ``dE/dt = H (v + p c) / (v + gamma p c)``.
        """
        active = [lk for lk in self.links if lk.enabled(valves)]
        lam = [(lk.a, lk.b, self.p_std / lk.resistance) for lk in active if lk.element is None]
        elems = [lk for lk in active if lk.element is not None]
        sources = [fs.node for fs in self.flow_sources if fs.valve is None or valves[fs.valve] == fs.when_open]
        n = self.n_nodes
        p_std = self.p_std
        p_atm = self.p_atm
        laws = list(laws)
        tau = max(regulator_tau, 1e-6)
        dyn = [(i, n + 1 + k, self.dampers[i]) for k, i in enumerate(self.dynamic)]
        dyn_slot = {i: s for i, s, _ in dyn}
        heat = [(i, self.amount_slot(i), self.thermal[i], dyn_slot.get(i)) for i in self.heated]
        n_state = self.n_state
        gm1 = GAMMA - 1.0

        def rhs(t: float, y: np.ndarray) -> np.ndarray:
            p = [laws[i].pressure_abs(y[i]) for i in range(n)]
            dy = np.zeros(n_state)
            for i, slot, b in dyn:
                v = max(y[slot], _MIN_VOLUME)
                p[i] = y[i] / v
                dy[slot] = (p[i] - p_atm - laws[i].pressure_for_volume(v)) / b
            th = [1.0] * n
            for i, ms, _, _ in heat:
                th[i] = y[i] / max(y[ms], 1e-300)
            dm = [0.0] * n  # amount in, net
            hin = [0.0] * n  # amount in weighted by its temperature, net
            p_reg = y[n]
            for a, b, g in lam:
                pa_ = p_reg if a == REGULATOR else (p_atm if a == ATMOSPHERE else p[a])
                pb_ = p_reg if b == REGULATOR else (p_atm if b == ATMOSPHERE else p[b])
                f = (pa_ - pb_) * g
                th_up = (th[a] if a >= 0 else 1.0) if f >= 0 else (th[b] if b >= 0 else 1.0)
                if a >= 0:
                    dm[a] -= f
                    hin[a] -= f * th_up
                if b >= 0:
                    dm[b] += f
                    hin[b] += f * th_up
            for lk in elems:
                a, b = lk.a, lk.b
                pa_ = p_reg if a == REGULATOR else (p_atm if a == ATMOSPHERE else p[a])
                pb_ = p_reg if b == REGULATOR else (p_atm if b == ATMOSPHERE else p[b])
                tha = th[a] if a >= 0 else 1.0
                thb = th[b] if b >= 0 else 1.0
                f = lk.amount_flow(pa_, pb_, tha, thb, p_std)
                th_up = tha if f >= 0 else thb
                if a >= 0:
                    dm[a] -= f
                    hin[a] -= f * th_up
                if b >= 0:
                    dm[b] += f
                    hin[b] += f * th_up
            if sources and flow_of_t is not None:
                q = p_std * flow_of_t(t)
                for node in sources:
                    dm[node] += q
                    hin[node] += q
            for i in range(n):
                dy[i] = dm[i]
            for i, ms, tw, vslot in heat:
                h = GAMMA * hin[i] + y[ms] * (1.0 - th[i]) / tw
                dy[ms] = dm[i]
                if vslot is not None:
                    dy[i] = h - gm1 * p[i] * dy[vslot]
                else:
                    v, c = laws[i].volume_compliance(p[i] - p_atm)
                    pc = p[i] * c
                    dy[i] = h * (v + pc) / (v + GAMMA * pc)
            dy[n] = (regulator_target_abs - p_reg) / tau
            return dy

        return rhs

    def link_flows(self, valves: dict[str, bool], p_abs: np.ndarray, p_reg: np.ndarray,
                   names: Sequence[str], theta: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Standard volumetric flow (m^3/s, positive a->b) through named links."""
        out: dict[str, np.ndarray] = {}
        ones = np.ones(p_reg.shape)
        for link in self.links:
            if link.name not in names:
                continue
            if not link.enabled(valves):
                out[link.name] = out.get(link.name, np.zeros(p_reg.shape))
                continue
            pa_ = p_reg if link.a == REGULATOR else (np.full_like(p_reg, self.p_atm) if link.a == ATMOSPHERE else p_abs[link.a])
            pb_ = p_reg if link.b == REGULATOR else (np.full_like(p_reg, self.p_atm) if link.b == ATMOSPHERE else p_abs[link.b])
            if link.element is None:
                q = (pa_ - pb_) / link.resistance
            else:
                tha = theta[link.a] if theta is not None and link.a >= 0 else ones
                thb = theta[link.b] if theta is not None and link.b >= 0 else ones
                q = np.array([link.amount_flow(x, z, u, w, self.p_std)
                              for x, z, u, w in zip(np.broadcast_to(pa_, p_reg.shape), np.broadcast_to(pb_, p_reg.shape),
                                                    tha, thb)]) / self.p_std
            out[link.name] = out.get(link.name, 0.0) + q
        return out
