"""fluidsense's box watchdog, as the emulated box runs it.

Like ur_rtde's control script (urscript.py), these programs are recognised, not
interpreted: the emulator reads from the program text what the program says (the
heartbeat register, the timeout, the outputs and their safe levels, the run-state
actions) and does that. A program generated wrong therefore acts wrong here too, which
is what the tests rely on. The generator is drivers/ur/watchdog.py.
"""

from __future__ import annotations

import logging
import re

from fluidsense.simulator.controlbox.box import ControlBox, Program, ProgramError

log = logging.getLogger(__name__)

_RUNSTATE = re.compile(r"^\s*set_runstate_(standard|configurable)_digital_output_to_value\(\s*(\d+)\s*,\s*(\d+)\s*\)",
                       re.M)
_SET_OUT = re.compile(r"set_(standard|configurable)_digital_out\(\s*(\d+)\s*,\s*(True|False)\s*\)")
_REGISTER = re.compile(r"^\s*HEARTBEAT_REGISTER\s*=\s*(\d+)\s*$", re.M)
_TIMEOUT = re.compile(r"^\s*TIMEOUT_S\s*=\s*([0-9.eE+-]+)\s*$", re.M)
_VENT = re.compile(r"^\s*def fluidsense_vent\(\):\s*\n(.*?)^\s*end\s*$", re.M | re.S)


def _output(bank: str, n: str) -> int:
    return int(n) + (8 if bank == "configurable" else 0)


def runstate_settings(source: str) -> list[tuple[int, int]]:
    """(output, run-state choice) of every run-state statement in ``source``."""
    return [(_output(bank, n), int(state)) for bank, n, state in _RUNSTATE.findall(source)]


def run_secondary(box: ControlBox, name: str, source: str) -> bool:
    """A secondary program runs beside the main one, at once. Only run-state statements
    are emulated; False when it holds none."""
    settings = runstate_settings(source)
    for output, state in settings:
        box.set_runstate(output, state)
    if settings:
        log.info("secondary program %s: run-state actions for outputs %s", name, [o for o, _ in settings])
    return bool(settings)


class WatchdogProgram(Program):
    """drivers/ur/watchdog.py's ``fluidsense_watchdog``: vents when the heartbeat register
    has not changed for the timeout, once per silence."""

    name = "fluidsense_watchdog"

    def __init__(self, register: int, timeout_s: float, vent: dict[int, bool], runstate: list[tuple[int, int]]):
        self.register, self.timeout_s, self.vent, self.runstate = register, timeout_s, vent, runstate
        self._last: int | None = None
        self._since = 0.0
        self._vented = False
        self.vents = 0  # how often it vented (inspection)

    @classmethod
    def from_source(cls, source: str) -> WatchdogProgram:
        reg, timeout, vent = _REGISTER.search(source), _TIMEOUT.search(source), _VENT.search(source)
        if reg is None or timeout is None or vent is None:
            raise ProgramError("fluidsense_watchdog: HEARTBEAT_REGISTER, TIMEOUT_S or fluidsense_vent() missing")
        levels = {_output(bank, n): level == "True" for bank, n, level in _SET_OUT.findall(vent.group(1))}
        return cls(int(reg.group(1)), float(timeout.group(1)), levels, runstate_settings(source))

    def start(self, box: ControlBox) -> None:
        for output, state in self.runstate:
            box.set_runstate(output, state)
        self._last = box.model.general_purpose(self.register - 128)
        self._since, self._vented = box.model.t, False
        log.info("fluidsense watchdog: register %d, %.3f s, vents outputs %s", self.register, self.timeout_s,
                 sorted(self.vent))

    def step(self, box: ControlBox) -> bool:
        beat, t = box.model.general_purpose(self.register - 128), box.model.t
        if beat != self._last:
            self._last, self._since, self._vented = beat, t, False
        elif t - self._since > self.timeout_s and not self._vented:
            mask = sum(1 << o for o in self.vent)
            bits = sum(int(level) << o for o, level in self.vent.items())
            box.set_digital_outputs(mask, bits, "watchdog")
            self._vented = True
            self.vents += 1
            log.warning("fluidsense watchdog: no heartbeat for %.3f s: valve outputs to their safe levels",
                        t - self._since)
        return True
