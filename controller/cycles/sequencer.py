"""Valve-sequencing state machine for one actuation cycle, written in sample time.

IDLE -> CHARGE -> ISOLATE -> ACTUATE -> HOLD -> VENT -> IDLE

CHARGE   regulator at P0 (tank: supply valve open, the tank fills). It ends only once the
         tank (or the regulated buffer) reads P0 within ``charge_tolerance_kpa``
         (``charged``, checked by the runner on its samples): the first cycle of a
         session starts from an empty tank, which a short ``charge_s`` may not fill; past
         ``charge_timeout_s`` more the cycle is aborted "not charged" (a supply below P0).
ISOLATE  tank method: supply valve closed, the tank holds its charge. Skipped when its
         duration is 0. The sensor offset is read just before the next step, while the
         actuator is still vented. The valve opens only once the vented actuator reads
         flat (``settled``, checked by the runner on its samples): until then the step
         lasts longer, and past ``settle_timeout_s`` the cycle is aborted "not settled".
         So every cycle, the first of a session too, starts from the same empty actuator
         and reads a true offset (paper, Methods: a blank for the sensor offset, then
         the mean of the last 0.5-1 s before the valve opens). Once settled, the tank
         (or the regulated buffer) must still read P0 (``charged``, below), else the
         cycle is aborted "not charged": a tank that leaked while isolated would give a
         wrong reading marked ok.
ACTUATE  actuation valve open (t_open): the actuator fills from the tank, the regulator
         or the flow controller.
HOLD     from the first measurement window until the valve closes.
VENT     every valve back to its safe position: the actuator vents.

``abort`` from any state goes to VENT with every valve in its safe position. The
machine does no I/O: it returns actions and the cycle runner applies them. Its only
clock is the sample time passed in, so the same code runs in real and virtual time.
"""

from __future__ import annotations

import enum
import logging
from collections.abc import Callable
from dataclasses import dataclass

from fluidsense.common.errors import SequenceError
from fluidsense.common.hardware import ACTUATE, SUPPLY, VENT
from fluidsense.common.units import SLPM
from fluidsense.controller.config import SequenceConfig

log = logging.getLogger(__name__)

SETTLE_RECHECK_S = 0.5  # while waiting for the actuator to settle, look again this often
CHARGE_RECHECK_S = 0.1  # while a tank charges on, look again this often (a tank fills in ~1 s)


class State(str, enum.Enum):
    IDLE = "idle"
    CHARGE = "charge"
    ISOLATE = "isolate"
    ACTUATE = "actuate"
    HOLD = "hold"
    VENT = "vent"
    FAULT = "fault"


@dataclass(frozen=True)
class ValveAction:
    valve: str
    open: bool


@dataclass(frozen=True)
class SetpointAction:
    pressure_pa: float


@dataclass(frozen=True)
class FlowProfileAction:
    """Piecewise-linear flow (standard m^3/s) at absolute sample times; zero after."""

    times: tuple[float, ...]
    flows: tuple[float, ...]


Action = ValveAction | SetpointAction | FlowProfileAction


@dataclass(frozen=True)
class Transition:
    t: float
    cycle_id: int
    source: State
    target: State
    reason: str


class Sequencer:
    """``valves``: the circuit's valves and their safe positions (name -> open)."""

    def __init__(self, cfg: SequenceConfig, valves: dict[str, bool] | None = None,
                 settled: Callable[[float], str | None] | None = None,
                 charged: Callable[[float], str | None] | None = None):
        """``settled(t)``: None when the vented actuator reads flat at ``t``, else why not
        (default: always flat); ``charged(t)``: None when the tank or buffer holds P0 at
        ``t``, else why not (default: always charged)."""
        self.cfg = cfg
        self._settled = settled or (lambda t: None)
        self._charged = charged or (lambda t: None)
        self._settle_since: float | None = None
        self._charge_since: float | None = None
        self.valves = dict(valves if valves is not None else {SUPPLY: False, ACTUATE: False})
        self.state = State.IDLE
        self.cycle_id = 0
        self.p0_pa = cfg.p0_pa
        self.t_start: float | None = None
        self.t_open: float | None = None
        self.t_end: float | None = None
        self.aborted: str | None = None
        self.hold = False
        self._deadline = float("inf")
        self._isolate_at = float("inf")
        self.transitions: list[Transition] = []

    @property
    def busy(self) -> bool:
        return self.state not in (State.IDLE, State.FAULT)

    def _go(self, t: float, target: State, reason: str) -> None:
        tr = Transition(t, self.cycle_id, self.state, target, reason)
        self.transitions.append(tr)
        log.info("cycle %d: %s -> %s at t=%.3f s (%s)", self.cycle_id, self.state.value,
                 target.value, t, reason)
        self.state = target

    def drain_transitions(self) -> list[Transition]:
        out, self.transitions = self.transitions, []
        return out

    def _safe(self) -> list[Action]:
        cmds: list[Action] = [ValveAction(name, pos) for name, pos in self.valves.items()]
        if self.cfg.method == "flow_control":
            cmds.append(FlowProfileAction((), ()))
        return cmds

    # ----------------------------------------------------------------- cycle
    def start(self, t: float, p0_pa: float | None = None, hold: bool = False) -> list[Action]:
        """Begin a cycle. With ``hold`` HOLD lasts until ``release`` instead of ``actuate_s``
        after opening (a gripper that carries what it measured)."""
        if self.state == State.FAULT:
            raise SequenceError("controller is in FAULT; reset first")
        if self.busy:
            raise SequenceError(f"a cycle is running (state {self.state.value})")
        self.cycle_id += 1
        self.p0_pa = self.cfg.p0_pa if p0_pa is None else p0_pa
        self.t_start, self.t_open, self.t_end, self.aborted = t, None, None, None
        self._isolate_at = float("inf")
        self._settle_since = self._charge_since = None
        self.hold = hold
        self._go(t, State.CHARGE, "start")
        self._deadline = t + self.cfg.charge_s
        tank = self.cfg.method == "tank"
        cmds: list[Action] = [c for c in self._safe() if not (tank and getattr(c, "valve", None) == SUPPLY)]
        if self.cfg.method != "flow_control":
            cmds.append(SetpointAction(self.p0_pa))
        if tank:
            cmds.append(ValveAction(SUPPLY, True))
        return cmds

    def on_time(self, t: float) -> list[Action]:
        """Advance with the newest sample time; returns the actions due now."""
        cmds: list[Action] = []
        if t >= self._isolate_at and self.state in (State.ACTUATE, State.HOLD):
            self._isolate_at = float("inf")
            log.info("cycle %d: actuator isolated at t=%.3f s", self.cycle_id, t)
            cmds.append(ValveAction(ACTUATE, False))
        while self.busy and t >= self._deadline:
            cmds += self._advance(t)
        return cmds

    def _advance(self, t: float) -> list[Action]:
        cfg = self.cfg
        if self.state == State.CHARGE:
            if (short := self._charged(t)) is not None:
                return self._charge_on(t, short)
            if self._charge_since is not None:
                log.info("cycle %d: tank charged after %.1f s more", self.cycle_id, t - self._charge_since)
            if cfg.isolate_s > 0:
                self._go(t, State.ISOLATE, "charged")
                self._deadline = t + cfg.isolate_s
                return [ValveAction(SUPPLY, False)] if cfg.method == "tank" else []
            return self._open_when_settled(t)
        if self.state == State.ISOLATE:
            return self._open_when_settled(t)
        if self.state == State.ACTUATE:
            self._go(t, State.HOLD, "measuring")
            self._deadline = float("inf") if self.hold else self.t_open + cfg.actuate_s
            return []
        if self.state == State.HOLD:
            self._go(t, State.VENT, "hold done")
            self._deadline = t + cfg.vent_s
            return self._safe()
        if self.state == State.VENT:
            self._go(t, State.IDLE, "aborted" if self.aborted else "done")
            self.t_end = t
            self._deadline = float("inf")
            return []
        raise SequenceError(f"no transition from {self.state}")  # pragma: no cover

    def _charge_on(self, t: float, short: str) -> list[Action]:
        """The tank is not at P0 yet: charge on and look again shortly, up to
        ``charge_timeout_s``, then refuse the cycle."""
        if self._charge_since is None:
            self._charge_since = t
            log.info("cycle %d: charging on: %s", self.cycle_id, short)
        waited = t - self._charge_since
        if waited >= self.cfg.charge_timeout_s:
            return self.abort(t, f"not charged: {short} after {waited:.0f} s more charging")
        self._deadline = t + CHARGE_RECHECK_S
        return []

    def _open_when_settled(self, t: float) -> list[Action]:
        """Open now if the vented actuator reads flat; else look again shortly, up to
        ``settle_timeout_s`` past the planned opening, then refuse the cycle."""
        why = self._settled(t) if self.cfg.settle_timeout_s > 0 else None
        if why is None:
            if self._settle_since is not None:
                log.info("cycle %d: actuator settled after %.1f s more", self.cycle_id, t - self._settle_since)
            if (short := self._charged(t)) is not None:
                return self.abort(t, f"not charged: {short}")
            return self._open(t)
        if self._settle_since is None:
            self._settle_since = t
            log.info("cycle %d: waiting for the vented actuator to settle: %s", self.cycle_id, why)
        waited = t - self._settle_since
        if waited >= self.cfg.settle_timeout_s:
            return self.abort(t, f"not settled: {why} after {waited:.0f} s more venting; the offset and the "
                              "gas the actuator starts with would be wrong (a leak into the actuator, a blocked "
                              "vent, a drifting sensor?)")
        self._deadline = t + SETTLE_RECHECK_S
        return []

    def _open(self, t: float) -> list[Action]:
        cfg = self.cfg
        self._go(t, State.ACTUATE, "valve open")
        self.t_open = t
        self._deadline = t + min(w.start_s for w in cfg.windows)
        if cfg.isolate_actuator_at_s is not None:
            self._isolate_at = t + cfg.isolate_actuator_at_s
        cmds: list[Action] = []
        if VENT in self.valves:
            cmds.append(ValveAction(VENT, False))
        cmds.append(ValveAction(ACTUATE, True))
        if cfg.method == "flow_control":
            fp = cfg.flow_profile
            q = fp.flow_slpm * SLPM
            t1 = t + fp.ramp_s
            t2 = t1 + fp.hold_s
            cmds.append(FlowProfileAction((t, t1, t2, t2 + 1e-6), (0.0, q, q, 0.0)))
        return cmds

    def release(self, t: float) -> list[Action]:
        """End a held cycle: to VENT now (from HOLD or, if the windows are still open,
        from ACTUATE: the measurement is then incomplete)."""
        if not self.busy:
            raise SequenceError("no cycle is running")
        if self.state not in (State.ACTUATE, State.HOLD):
            raise SequenceError(f"cannot release in state {self.state.value}")
        self._go(t, State.VENT, "released")
        self._deadline = t + self.cfg.vent_s
        self._isolate_at = float("inf")
        return self._safe()

    def abort(self, t: float, reason: str) -> list[Action]:
        """Go to VENT from any running state: every valve to its safe position."""
        if not self.busy:
            return []
        self.aborted = self.aborted or reason
        self._isolate_at = float("inf")
        if self.state != State.VENT:
            self._go(t, State.VENT, f"abort: {reason}")
            self._deadline = t + self.cfg.vent_s
        return self._safe()

    def fault(self, t: float, reason: str) -> list[Action]:
        """Latch FAULT (safe state) until ``reset``."""
        self.aborted = self.aborted or reason
        self._isolate_at = float("inf")
        if self.state != State.FAULT:
            self._go(t, State.FAULT, reason)
        self._deadline = float("inf")
        return self._safe()

    def reset(self, t: float) -> None:
        if self.state == State.FAULT:
            self._go(t, State.IDLE, "reset")
