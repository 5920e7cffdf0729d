"""Valve-sequencing state machine for one actuation cycle, written in sample time.

IDLE -> CHARGE -> ISOLATE -> ACTUATE -> HOLD -> VENT -> IDLE

CHARGE   regulator at P0, supply valve open: the tank fills.
ISOLATE  supply valve closed: the tank holds its charge; the sensor offset is read at
         the end of this state, with the actuator still vented.
ACTUATE  actuation valve open (t_open): the actuator inflates from the tank.
HOLD     from the first measurement window until the valve closes.
VENT     actuation valve closed: the actuator vents.

``abort`` from any state goes to VENT with every valve closed. The machine does no I/O:
it returns commands, and the controller applies them. Its only clock is the sample time
passed in, so the same code runs in real and virtual time.
"""

from __future__ import annotations

import enum
import logging
from dataclasses import dataclass

from drivers.errors import SequenceError

from .config import SequenceConfig

log = logging.getLogger(__name__)


class State(str, enum.Enum):
    IDLE = "idle"
    CHARGE = "charge"
    ISOLATE = "isolate"
    ACTUATE = "actuate"
    HOLD = "hold"
    VENT = "vent"
    FAULT = "fault"


@dataclass(frozen=True)
class ValveCmd:
    valve: str
    open: bool


@dataclass(frozen=True)
class SetpointCmd:
    pressure_pa: float


Command = ValveCmd | SetpointCmd


@dataclass(frozen=True)
class Transition:
    t: float
    cycle_id: int
    source: State
    target: State
    reason: str


class Sequencer:
    def __init__(self, cfg: SequenceConfig):
        self.cfg = cfg
        self.state = State.IDLE
        self.cycle_id = 0
        self.p0_pa = cfg.p0_kpa * 1e3
        self.t_start: float | None = None
        self.t_open: float | None = None
        self.t_end: float | None = None
        self.aborted: str | None = None
        self._deadline = float("inf")
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

    def start(self, t: float, p0_pa: float | None = None) -> list[Command]:
        if self.state == State.FAULT:
            raise SequenceError("controller is in FAULT; reset first")
        if self.busy:
            raise SequenceError(f"a cycle is running (state {self.state.value})")
        self.cycle_id += 1
        self.p0_pa = self.cfg.p0_kpa * 1e3 if p0_pa is None else p0_pa
        self.t_start, self.t_open, self.t_end, self.aborted = t, None, None, None
        self._go(t, State.CHARGE, "start")
        self._deadline = t + self.cfg.charge_s
        return [ValveCmd("actuate", False), SetpointCmd(self.p0_pa), ValveCmd("supply", True)]

    def on_time(self, t: float) -> list[Command]:
        """Advance with the newest sample time; returns the commands due now."""
        cmds: list[Command] = []
        while self.busy and t >= self._deadline:
            cmds += self._advance(t)
        return cmds

    def _advance(self, t: float) -> list[Command]:
        cfg = self.cfg
        if self.state == State.CHARGE:
            self._go(t, State.ISOLATE, "charged")
            self._deadline = t + cfg.isolate_s
            return [ValveCmd("supply", False)]
        if self.state == State.ISOLATE:
            self._go(t, State.ACTUATE, "valve open")
            self.t_open = t
            first_window = min(w.start_s for w in cfg.windows)
            self._deadline = t + first_window
            return [ValveCmd("actuate", True)]
        if self.state == State.ACTUATE:
            self._go(t, State.HOLD, "measuring")
            self._deadline = self.t_open + cfg.actuate_s
            return []
        if self.state == State.HOLD:
            self._go(t, State.VENT, "hold done")
            self._deadline = t + cfg.vent_s
            return [ValveCmd("actuate", False)]
        if self.state == State.VENT:
            self._go(t, State.IDLE, "aborted" if self.aborted else "done")
            self.t_end = t
            self._deadline = float("inf")
            return []
        raise SequenceError(f"no transition from {self.state}")  # pragma: no cover

    def abort(self, t: float, reason: str) -> list[Command]:
        """Go to VENT from any running state: every valve closed."""
        if not self.busy:
            return []
        self.aborted = self.aborted or reason
        if self.state != State.VENT:
            self._go(t, State.VENT, f"abort: {reason}")
            self._deadline = t + self.cfg.vent_s
        return [ValveCmd("actuate", False), ValveCmd("supply", False)]

    def fault(self, t: float, reason: str) -> list[Command]:
        """Latch FAULT (safe state) until ``reset``."""
        self.aborted = self.aborted or reason
        if self.state != State.FAULT:
            self._go(t, State.FAULT, reason)
        self._deadline = float("inf")
        return [ValveCmd("actuate", False), ValveCmd("supply", False)]

    def reset(self, t: float) -> None:
        if self.state == State.FAULT:
            self._go(t, State.IDLE, "reset")
