"""The controller around the model: registers, the running program, safety reactions,
and the glue every protocol server writes through.

Everything runs on the emulator's asyncio loop. ``tick()`` is called at the control rate
(500 Hz e-Series, 125 Hz CB3); it brings the model to the current time, reacts to safety
stops, and steps the running program one controller cycle, which is what URScript's
``sync()`` waits for. The inputs Modbus and RTDE report come from an I/O image refreshed
on the box's clock at the I/O rate (the control rate), as a real box does: a client
polling faster reads the same value again.
"""

from __future__ import annotations

import abc
import enum
import logging
import math
from collections import deque
from collections.abc import Callable
from typing import Any

from fluidsense.common.errors import SafetyError
from fluidsense.simulator.controlbox.config import ControlBoxConfig
from fluidsense.simulator.controlbox.lies import Lies
from fluidsense.simulator.controlbox.model import (
    N_ANALOG,
    AnalogDomain,
    AnalogSignal,
    ControlBoxModel,
    RobotMode,
    SafetyMode,
)
from fluidsense.simulator.controlbox.registers import Registers

log = logging.getLogger(__name__)

#: how hard the arm brakes when a program is stopped or paused (m/s^2)
PROGRAM_STOP_DECELERATION = 3.0

# (mask variable, value variable, first output bit) of RTDE's digital output inputs
_DIGITAL_GROUPS = (
    ("standard_digital_output_mask", "standard_digital_output", 0),
    ("configurable_digital_output_mask", "configurable_digital_output", 8),
    ("tool_digital_output_mask", "tool_digital_output", 16),
)


class RuntimeState(enum.IntEnum):
    """RTDE ``runtime_state``."""

    STOPPING = 0
    STOPPED = 1
    PLAYING = 2
    PAUSING = 3
    PAUSED = 4
    RESUMING = 5


class Program(abc.ABC):
    """Something the controller runs: one step per controller cycle."""

    name: str = "<program>"

    def start(self, box: ControlBox) -> None:
        """Called once when the program starts."""

    @abc.abstractmethod
    def step(self, box: ControlBox) -> bool:
        """One controller cycle; False when the program has ended."""

    def stopped(self, box: ControlBox) -> None:
        """Called once when the program is stopped from outside (or fails)."""

    def paused(self, box: ControlBox) -> None:
        """The arm was stopped for a pause."""

    def resumed(self, box: ControlBox) -> None:
        """The pause is over: pick up interrupted motion."""


class IdleProgram(Program):
    """A program loaded through the dashboard: its content is not interpreted, so it runs
    (doing nothing) until stopped."""

    def __init__(self, name: str):
        self.name = name

    def step(self, box: ControlBox) -> bool:
        return True


class ProgramError(SafetyError):
    """The running program failed (unsupported command, refused motion)."""


class ControlBox:
    """State shared by the servers: the model, registers, program and input claims."""

    def __init__(self, config: ControlBoxConfig, model: ControlBoxModel, clock: Callable[[], float]):
        self.config = config
        self.model = model
        self.registers = Registers()
        self._clock = clock
        self._t0 = clock()
        self.program: Program | None = None
        self.runtime_state = RuntimeState.STOPPED
        self.loaded_program: str | None = None
        #: input variable -> owner (an RTDE session); a variable has one writer
        self.input_owners: dict[str, object] = {}
        #: latest value and model time of every input variable written over RTDE
        self.input_values: dict[str, Any] = {}
        self.input_times: dict[str, float] = {}
        self.protective_since: float | None = None
        self.shutdown_requested: Callable[[], None] | None = None
        #: digital output -> URScript run-state choice (set_runstate_*_digital_output_to_value)
        self.runstate: dict[int, int] = {}
        #: every change of the digital outputs: (model time, outputs after, who changed them)
        self.journal: deque[tuple[float, int, str]] = deque(maxlen=500)
        #: the network as a person at the cell leaves it (sim control ``network``); the
        #: emulator closes and reopens its ports when this is asked for
        self.network_up = True
        self.network_requested: Callable[[bool], None] | None = None
        #: (max_hz, lag_s): RTDE output streams at max_hz or slower reach their clients
        #: lag_s late (sim control ``rtde_lag``), as a receive thread starved on a busy PC
        #: reads them; (0, 0): none
        self.rtde_lag: tuple[float, float] = (0.0, 0.0)
        self.lies = Lies()  # what the box says that cannot be true (sim control ``lie``)
        self._outputs_seen = model.digital_outputs  # the digital outputs as the last change left them
        #: the I/O image: the inputs as read at the start of the current I/O cycle (number
        #: ``io_cycle``, at ``io_cycle / config.io_hz`` s); what Modbus and RTDE report
        self.io_cycle = 0
        self.latch_inputs()

    # -- time ----------------------------------------------------------------------------------
    def now(self) -> float:
        """Seconds since the emulator started."""
        return self._clock() - self._t0

    def sync(self) -> float:
        """Bring the model to now (before applying anything that happens now); on the way,
        refresh the I/O image with the inputs at the last I/O cycle's start. A cycle nobody
        looked at is skipped: the image changes at most once per cycle, never in a burst."""
        t = self.now()
        cycle = math.floor(t * self.config.io_hz)
        if cycle > self.io_cycle:
            start = cycle / self.config.io_hz
            if start > self.model.t:
                self.model.advance(start)
            cycles, self.io_cycle = cycle - self.io_cycle, cycle
            if not self.lies.frozen(start, cycles):  # a frozen box (sim control lie) keeps its image
                self.latch_inputs()
        if t > self.model.t:
            self.model.advance(t)
        return self.model.t

    def latch_inputs(self) -> None:
        """Take the model's inputs into the I/O image (each I/O cycle; the sim control
        channel also at once after it set an input, so that a test reads what it set)."""
        m = self.model
        self.image_digital_inputs = m.digital_inputs
        self.image_analog_inputs = [m.analog_input(ch) for ch in range(N_ANALOG)]

    def tick(self) -> None:
        """One controller cycle."""
        t = self.sync()
        self._watch_safety(t)
        if self.program is not None and self.runtime_state == RuntimeState.PLAYING:
            try:
                running = self.program.step(self)
            except ProgramError as exc:
                log.error("program %s failed: %s", self.program.name, exc)
                self.stop_program(f"runtime error: {exc}")
            else:
                if not running:
                    log.info("program %s ended", self.program.name)
                    self.program = None
                    self.runtime_state = RuntimeState.STOPPED
        if not self.program_running:
            self._hold_runstate()

    # -- run-state output actions ----------------------------------------------------------------
    #: choice -> level while no program runs (0 preserves the output, as do the choices that
    #: act on drive power or on unscheduled stops only, not emulated)
    _RUNSTATE_STOPPED_LEVEL = {1: False, 2: True, 3: False}

    def set_runstate(self, output: int, state: int) -> None:
        if not 0 <= state <= 7:
            raise ProgramError(f"run-state {state} for output {output}: expected 0..7")
        self.runstate[output] = state
        log.info("output %d: run-state %d", output, state)

    def _held(self) -> tuple[int, int]:
        """(mask, bits) of the outputs a run-state action holds while no program runs."""
        mask = bits = 0
        if self.program_running:
            return 0, 0
        for output, state in self.runstate.items():
            level = self._RUNSTATE_STOPPED_LEVEL.get(state)
            if level is not None:
                mask |= 1 << output
                bits |= int(level) << output
        return mask, bits

    def _hold_runstate(self) -> None:
        """While no program runs, outputs with a run-state action are held at its level
        (writes to them are ignored meanwhile)."""
        mask, bits = self._held()
        if mask and self.model.digital_outputs & mask != bits:
            self.sync()
            self.model.set_digital_outputs(mask, bits)
            self._outputs_changed("runstate")

    def _watch_safety(self, t: float) -> None:
        model = self.model
        if model.protective_stop:
            if self.protective_since is None:
                self.protective_since = t
        else:
            self.protective_since = None
        if self.runtime_state != RuntimeState.STOPPED and not model.may_move():
            # Any safety stop, power off or brake engagement ends the program; ur_rtde
            # recovers with unlock + reuploadScript.
            self.stop_program(f"robot mode {model.robot_mode.name}, safety mode {model.safety_mode.name}")

    # -- programs --------------------------------------------------------------------------------
    def run_program(self, program: Program) -> bool:
        """Start ``program`` (replacing a running one); False if the robot cannot run it."""
        if not self.model.may_move():
            log.warning("program %s not started: robot mode %s, safety mode %s", program.name,
                        self.model.robot_mode.name, self.model.safety_mode.name)
            return False
        if self.program is not None and self.runtime_state != RuntimeState.STOPPED:
            self.stop_program(f"replaced by {program.name}")
        self.program = program
        self.runtime_state = RuntimeState.PLAYING
        log.info("program %s started", program.name)
        program.start(self)
        return True

    def stop_program(self, reason: str) -> None:
        program, self.program = self.program, None
        was = self.runtime_state
        self.runtime_state = RuntimeState.STOPPED
        if program is None or was == RuntimeState.STOPPED:
            return
        log.info("program %s stopped: %s", program.name, reason)
        program.stopped(self)
        self._brake()

    def pause_program(self) -> bool:
        if self.program is None or self.runtime_state != RuntimeState.PLAYING:
            return False
        self.runtime_state = RuntimeState.PAUSED
        self._brake()
        self.program.paused(self)
        log.info("program %s paused", self.program.name)
        return True

    def resume_program(self) -> bool:
        if self.program is None or self.runtime_state != RuntimeState.PAUSED or not self.model.may_move():
            return False
        self.runtime_state = RuntimeState.PLAYING
        self.program.resumed(self)
        log.info("program %s resumed", self.program.name)
        return True

    def _brake(self) -> None:
        if self.model.is_moving():
            self.model.stop(PROGRAM_STOP_DECELERATION)

    @property
    def program_running(self) -> bool:
        return self.program is not None and self.runtime_state == RuntimeState.PLAYING

    # -- outputs (every writer goes through here so the model hears about changes) ---------------
    def set_digital_outputs(self, mask: int, bits: int, by: str) -> None:
        """``by``: who asks (modbus, rtde, a program), for the journal."""
        self.sync()
        mask &= ~self._held()[0]
        before = self.model.digital_outputs
        self.model.set_digital_outputs(mask, bits)
        if self.model.digital_outputs != before:
            self._outputs_changed(by)

    def set_analog_output(self, channel: int, value: float, domain: AnalogDomain) -> None:
        self.sync()
        before = self.model.analog_output(channel)
        self.model.set_analog_output(channel, value, domain)
        if self.model.analog_output(channel) != before:
            self._outputs_changed()

    def _outputs_changed(self, by: str | None = None) -> None:
        if by is not None:
            self.journal.append((self.model.t, self.model.digital_outputs, by))
        self.model.on_outputs_changed(self.model.t)
        before, self._outputs_seen = self._outputs_seen, self.model.digital_outputs
        self.lies.outputs_changed(self.model.t, before, self._outputs_seen)  # an armed lie may begin

    # -- RTDE inputs -------------------------------------------------------------------------------
    def write_inputs(self, values: dict[str, Any]) -> None:
        """Apply one RTDE input package (all its fields at the same instant)."""
        t = self.sync()
        for name, value in values.items():
            self.input_values[name] = value
            self.input_times[name] = t
            if name.startswith("input_"):
                self.registers.write(name, value)
        digital = self._apply_digital(values)
        analog = self._apply_analog(values)
        if "speed_slider_mask" in values and values["speed_slider_mask"] & 1:
            self.model.speed_fraction = min(1.0, max(0.0, float(self.input_values.get("speed_slider_fraction", 1.0))))
        if digital or analog:
            self._outputs_changed("rtde" if digital else None)

    def _apply_digital(self, values: dict[str, Any]) -> bool:
        changed = False
        for mask_name, value_name, first in _DIGITAL_GROUPS:
            if mask_name not in values:
                continue
            mask = int(values[mask_name]) << first & ~self._held()[0]
            bits = int(self.input_values.get(value_name, 0)) << first
            before = self.model.digital_outputs
            self.model.set_digital_outputs(mask, bits)
            changed |= self.model.digital_outputs != before
        return changed

    def _apply_analog(self, values: dict[str, Any]) -> bool:
        if "standard_analog_output_mask" not in values:
            return False
        mask = int(values["standard_analog_output_mask"])
        types = int(self.input_values.get("standard_analog_output_type", 0))
        changed = False
        for ch in range(N_ANALOG):
            if not mask & (1 << ch):
                continue
            domain = AnalogDomain.VOLTAGE if types & (1 << ch) else AnalogDomain.CURRENT
            ratio = float(self.input_values.get(f"standard_analog_output_{ch}", 0.0))
            if not math.isfinite(ratio):
                log.warning("analog output %d: ignoring non-finite ratio %r", ch, ratio)
                continue
            lo, hi = self.config.analog.span(domain)
            value = lo + min(1.0, max(0.0, ratio)) * (hi - lo)
            before = self.model.analog_output(ch)
            self.model.set_analog_output(ch, value, domain)
            changed |= self.model.analog_output(ch) != before
        return changed

    # -- derived status ------------------------------------------------------------------------------
    def robot_status_bits(self) -> int:
        """Bits 0-3: power on | program running | teach button | power button."""
        powered = self.model.robot_mode in (RobotMode.POWER_ON, RobotMode.IDLE, RobotMode.BACKDRIVE,
                                            RobotMode.RUNNING)
        return int(powered) | (int(self.program_running) << 1)

    def safety_status_bits(self) -> int:
        """Bits 0-10: normal | reduced | protective stopped | recovery | safeguard stopped |
        system e-stop | robot e-stop | e-stop | violation | fault | stopped due to safety."""
        mode = self.model.safety_mode
        bit = {SafetyMode.NORMAL: 0, SafetyMode.REDUCED: 1, SafetyMode.PROTECTIVE_STOP: 2,
               SafetyMode.RECOVERY: 3, SafetyMode.SAFEGUARD_STOP: 4, SafetyMode.SYSTEM_EMERGENCY_STOP: 5,
               SafetyMode.ROBOT_EMERGENCY_STOP: 6, SafetyMode.VIOLATION: 8, SafetyMode.FAULT: 9}
        bits = 1 << bit[mode]
        if mode in (SafetyMode.SYSTEM_EMERGENCY_STOP, SafetyMode.ROBOT_EMERGENCY_STOP):
            bits |= 1 << 7
        if mode not in (SafetyMode.NORMAL, SafetyMode.REDUCED):
            bits |= 1 << 10
        return bits

    def analog_io_types(self) -> int:
        """Bits 0-3: analog input 0 | input 1 | output 0 | output 1; 1 = voltage."""
        m = self.model
        domains = [m.analog_input(0), m.analog_input(1), m.analog_output(0), m.analog_output(1)]
        return sum(int(sig.domain == AnalogDomain.VOLTAGE) << i for i, sig in enumerate(domains))

    @staticmethod
    def rtde_analog_value(signal: AnalogSignal) -> float:
        """RTDE reports analog I/O in V or mA."""
        return signal.value if signal.domain == AnalogDomain.VOLTAGE else signal.value * 1e3

    # -- inspection (the sim control channel) ------------------------------------------------------------
    def snapshot(self) -> dict[str, Any]:
        m = self.model
        return {
            "t": m.t, "tcp_pose": list(m.tcp_pose), "tcp_speed": list(m.tcp_speed), "moving": m.is_moving(),
            "digital_inputs": m.digital_inputs, "digital_outputs": m.digital_outputs,
            "analog_inputs": [{"value": m.analog_input(i).value, "domain": m.analog_input(i).domain.name}
                              for i in range(N_ANALOG)],
            "analog_outputs": [{"value": m.analog_output(i).value, "domain": m.analog_output(i).domain.name}
                               for i in range(N_ANALOG)],
            "speed_fraction": m.speed_fraction, "robot_mode": m.robot_mode.name, "safety_mode": m.safety_mode.name,
            "protective_stop": m.protective_stop, "emergency_stop": m.emergency_stop,
            "runtime_state": self.runtime_state.name, "program": self.program.name if self.program else None,
            "input_int_registers": list(self.registers.ints["input"]),
            "input_double_registers": list(self.registers.doubles["input"]),
            "output_int_registers": list(self.registers.ints["output"]),
            "output_double_registers": list(self.registers.doubles["output"]),
            "runstate": {str(o): s for o, s in sorted(self.runstate.items())},
            "output_journal": [list(e) for e in self.journal],
            "network_up": self.network_up, "controller": self.config.controller, "io_hz": self.config.io_hz,
        }
