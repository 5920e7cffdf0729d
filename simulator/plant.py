"""The simulated pneumatic plant: a gas network integrated between discrete events.

Between two events (a valve switching, a regulator setpoint, a scene change) the
network is a fixed ODE; it is solved with scipy's LSODA (it switches to a stiff method
when the resistor is small) and the dense solution is evaluated at the sample instants.
Events are applied exactly at their time, so the samples depend only on the event
times, never on how the caller splits its requests into blocks.
"""

from __future__ import annotations

import heapq
import itertools
import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from fluidsense.simulator.gas import Network, VolumeLaw
from scipy.integrate import solve_ivp

log = logging.getLogger(__name__)

_RTOL = 1e-9
_FIRST_HORIZON_S = 2.0
_MAX_HORIZON_S = 120.0


@dataclass
class _Segment:
    t0: float
    y0: np.ndarray
    rhs: Callable
    t_end: float
    # dense solutions (t_start, t_end, OdeSolution) covering [t0, t_end], oldest first
    pieces: list = field(default_factory=list)
    steady: bool = False  # nothing moves after t_end: the state stays y_end
    y_end: np.ndarray | None = None
    horizon: float = _FIRST_HORIZON_S


@dataclass(order=True)
class _Event:
    t: float
    seq: int
    apply: Callable[[], None] = field(compare=False)
    what: str = field(compare=False, default="")


class Plant:
    """Owns the network state, the valve states and a queue of timed events."""

    def __init__(self, network: Network, valves: dict[str, bool], p_reg_abs: float,
                 regulator_tau_s: float, t0: float = 0.0, p_initial_abs: dict[str, float] | None = None):
        self.net = network
        self.valves = dict(valves)
        self.laws = list(network.laws)
        self.regulator_target_abs = p_reg_abs
        self.regulator_tau_s = regulator_tau_s
        self.flow_of_t: Callable[[float], float] | None = None
        self._events: list[_Event] = []
        self._seq = itertools.count()
        # s of the first solve after an event (then doubling): long in virtual time, where
        # fewer solves are cheaper; short where the plant runs in real time beside I/O, so
        # that no one solve holds the box's loop for longer than its I/O period
        self.first_horizon_s = _FIRST_HORIZON_S
        # the solver's relative tolerance (absolute: 1 % of it, relative to each state)
        self.rtol = _RTOL
        y0 = np.empty(network.n_state)
        p_initial_abs = p_initial_abs or {}
        for i, name in enumerate(network.names):
            p_abs = p_initial_abs.get(name, network.p_atm)
            y0[i] = self.laws[i].amount_at(p_abs - network.p_atm)
            slot = network.volume_slot(i)
            if slot is not None:  # a damped actuator starts at rest: on its law
                y0[slot] = float(self.laws[i].volume_at(p_abs - network.p_atm))
            ms = network.amount_slot(i)
            if ms is not None:  # every volume starts at the wall's temperature
                y0[ms] = y0[i]
        y0[network.n_nodes] = p_reg_abs
        self._seg = self._new_segment(t0, y0)
        self.n_solves = 0

    # ----------------------------------------------------------------- events
    def schedule(self, t: float, apply: Callable[[], None], what: str = "") -> None:
        """Run ``apply`` at plant time ``t`` (it changes valves, laws, setpoints...)."""
        heapq.heappush(self._events, _Event(float(t), next(self._seq), apply, what))

    def cancel_laws(self, node: str, kind: str, from_t: float) -> int:
        """Drop the law changes of ``node`` scheduled as ``kind`` (``schedule_law``) and due
        at or after ``from_t`` (not yet applied: applied ones are out of the queue); how many."""
        what = f"law {node} {kind}"
        kept = [ev for ev in self._events if ev.what != what or ev.t < from_t]
        dropped = len(self._events) - len(kept)
        if dropped:
            heapq.heapify(kept)
            self._events = kept
        return dropped

    def schedule_valve(self, t: float, valve: str, open_: bool) -> None:
        if valve not in self.valves:
            raise KeyError(valve)

        def apply() -> None:
            self.valves[valve] = open_

        self.schedule(t, apply, f"valve {valve}={'open' if open_ else 'closed'}")

    def schedule_regulator(self, t: float, target_abs: float) -> None:
        def apply() -> None:
            self.regulator_target_abs = target_abs

        self.schedule(t, apply, "regulator")

    def schedule_law(self, t: float, node: str, law: VolumeLaw, kind: str = "set") -> None:
        """``kind`` names the change for ``cancel_laws``: the cell sets a scene's law
        ("set") and refreshes a moving scene's ("refresh")."""
        i = self.net.index[node]

        def apply() -> None:
            self.laws[i] = law

        self.schedule(t, apply, f"law {node} {kind}")

    def schedule_scale(self, t: float, node: str, factor: float) -> None:
        """Multiply the gas in a node at time t: what warming a closed volume does to its
        pressure (p*v = m*T/T0 with m fixed: scaling m is scaling T)."""
        i = self.net.index[node]
        ms = self.net.amount_slot(i)

        def apply() -> None:
            self._seg.y0[i] *= factor
            if ms is not None:  # the same warming, as more gas at the temperature it had
                self._seg.y0[ms] *= factor

        self.schedule(t, apply, f"scale {node} x{factor:.4f}")

    def schedule_pressure(self, t: float, node: str, p_abs: float) -> None:
        """Set a node's pressure at time t (an operator bleeding or topping up a volume)."""
        i = self.net.index[node]

        slot = self.net.volume_slot(i)
        ms = self.net.amount_slot(i)

        def apply() -> None:
            y = self._seg.y0
            theta = y[i] / y[ms] if ms is not None else 1.0
            if slot is None:
                y[i] = self.laws[i].amount_at(p_abs - self.net.p_atm)
            else:  # the structure does not move in the instant: the gas amount does
                y[i] = p_abs * y[slot]
            if ms is not None:  # gas added or bled at the temperature the volume has
                y[ms] = y[i] / theta

        self.schedule(t, apply, f"set {node} to {p_abs:.0f} Pa")

    def schedule_flow(self, t: float, flow_of_t: Callable[[float], float] | None) -> None:
        def apply() -> None:
            self.flow_of_t = flow_of_t

        self.schedule(t, apply, "flow")

    @property
    def next_event_time(self) -> float:
        return self._events[0].t if self._events else float("inf")

    # ---------------------------------------------------------------- solving
    def _new_segment(self, t0: float, y0: np.ndarray) -> _Segment:
        rhs = self.net.rhs_factory(self.valves, self.laws, self.regulator_target_abs,
                                   self.regulator_tau_s, self.flow_of_t)
        return _Segment(t0=t0, y0=np.array(y0, dtype=float), rhs=rhs, t_end=t0, horizon=self.first_horizon_s)

    def _atol(self, y: np.ndarray) -> np.ndarray:
        scale = np.maximum(np.abs(y), 1e-6)
        return scale * self.rtol * 1e-2

    def _extend(self, seg: _Segment, t_needed: float) -> None:
        """Integrate the segment forward until it covers ``t_needed``."""
        while seg.t_end < t_needed and not seg.steady:
            y_start = seg.y0 if seg.y_end is None else seg.y_end
            t_start = seg.t_end
            t_stop = max(t_needed, t_start + seg.horizon)
            seg.horizon = min(seg.horizon * 2.0, _MAX_HORIZON_S)
            res = solve_ivp(seg.rhs, (t_start, t_stop), y_start, method="LSODA",
                            dense_output=True, rtol=self.rtol, atol=self._atol(y_start))
            self.n_solves += 1
            if not res.success:  # pragma: no cover - LSODA failing is a model bug
                raise RuntimeError(f"plant integration failed: {res.message}")
            seg.pieces.append((t_start, t_stop, res.sol))
            seg.t_end = t_stop
            seg.y_end = res.y[:, -1].copy()
            # Settled: nothing changes any more within the integration tolerance.
            if self.flow_of_t is None:
                dy = seg.rhs(t_stop, seg.y_end)
                if np.all(np.abs(dy) * _MAX_HORIZON_S <= self._atol(seg.y_end)):
                    seg.steady = True

    def _state(self, seg: _Segment, t: np.ndarray) -> np.ndarray:
        """State at times ``t`` (sorted, all >= seg.t0), shape (n_state, len(t))."""
        t = np.asarray(t, dtype=float)
        self._extend(seg, float(t[-1]))
        # requests only move forward: pieces that end before this one are done
        while len(seg.pieces) > 1 and seg.pieces[0][1] < t[0]:
            seg.pieces.pop(0)
        out = np.empty((len(seg.y0), len(t)))
        done = np.zeros(len(t), dtype=bool)
        if not seg.pieces:
            out[:] = seg.y0[:, None]
            return out
        for t_a, t_b, sol in seg.pieces:
            sel = ~done & (t <= t_b)
            if sel.any():
                out[:, sel] = sol(t[sel])
                done |= sel
        if not done.all():  # steady tail
            out[:, ~done] = seg.y_end[:, None]
        return out

    def _jump_to(self, t: float) -> None:
        """Make ``t`` the start of a new segment (state continuous, new RHS)."""
        seg = self._seg
        y = self._state(seg, np.array([t]))[:, 0] if t > seg.t0 else seg.y0
        self._seg = self._new_segment(t, y)

    # -------------------------------------------------------------- sampling
    def sample(self, times: np.ndarray, flow_links: dict[str, float] | None = None,
               flow_sources: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
        """State at the sample instants (sorted, not before the segment start).

        Returns (state, flow): state has shape (n_state, len(times)), p*v per node (the
        gas amounts of isothermal nodes), the regulator output, the volumes of damped
        nodes, then the amounts of heat-exchanging nodes; flow (standard m^3/s, or None when not asked for) is
        the signed sum over ``flow_links`` (link name -> sign) of the flow through each,
        plus the flow sources when ``flow_sources``. Events due at or before a sample
        instant are applied before it.
        """
        times = np.asarray(times, dtype=float)
        out = np.empty((self.net.n_state, len(times)))
        flow = np.zeros(len(times)) if flow_links is not None else None
        i = 0
        while i < len(times):
            t_ev = self.next_event_time
            j = int(np.searchsorted(times, t_ev, side="left"))
            if j > i:
                out[:, i:j] = self._state(self._seg, times[i:j])
                if flow is not None:
                    flow[i:j] = self._flow(times[i:j], out[:, i:j], flow_links, flow_sources)
                i = j
            if i < len(times):
                t_apply = max(t_ev, self._seg.t0)
                self._jump_to(t_apply)
                while self._events and self._events[0].t <= t_apply:
                    ev = heapq.heappop(self._events)
                    ev.apply()
                    log.debug("plant t=%.4f: %s", t_apply, ev.what)
                self._seg = self._new_segment(self._seg.t0, self._seg.y0)
        return out, flow

    def _flow(self, t: np.ndarray, state: np.ndarray, links: dict[str, float], sources: bool) -> np.ndarray:
        p_abs = self.pressures_abs(state)
        theta = self.net.theta(state) if self.net.heated else None
        flows = self.net.link_flows(self.valves, p_abs, state[self.net.n_nodes], list(links), theta)
        total = sum(sign * flows[name] for name, sign in links.items())
        total = np.zeros(len(t)) + total
        if sources and self.flow_of_t is not None and any(
                fs.valve is None or self.valves[fs.valve] == fs.when_open for fs in self.net.flow_sources):
            total = total + self.flow_of_t(t)  # vectorised: np.interp profiles
        return total

    def check_resample_from(self, t: float) -> None:
        """Refuse (RuntimeError) to sample again from ``t`` if an event was applied after it.

        The plant's solution is continuous within a segment, so samples dropped by the cell
        can be recomputed from any ``t`` within the current segment.
        """
        if t < self._seg.t0 - 1e-12:
            raise RuntimeError(f"cannot sample the plant again from t={t}: an event was applied at {self._seg.t0}")

    def pressures_abs(self, state: np.ndarray) -> np.ndarray:
        """Absolute pressure of every node for a state array from ``sample``."""
        rows = []
        for i in range(self.net.n_nodes):
            slot = self.net.volume_slot(i)
            if slot is None:
                rows.append(self.laws[i].pressure_abs_array(state[i]))
            else:
                rows.append(state[i] / np.maximum(state[slot], 1e-12))
        return np.vstack(rows)

    def volumes(self, state: np.ndarray, node: str) -> np.ndarray:
        """Volume (m^3) of a node for a state array from ``sample``: the damped state, or
        the law at the node's pressure."""
        i = self.net.index[node]
        slot = self.net.volume_slot(i)
        if slot is not None:
            return state[slot]
        return self.laws[i].volume_at(self.pressures_abs(state)[i] - self.net.p_atm)

    def amounts_now(self) -> np.ndarray:
        return self._seg.y0.copy()
