"""The control box vents the gripper by itself when the service stops talking to it.

A UR control box keeps its digital outputs as they were last set: if the PC, the daemon
or the link dies with the actuation valve open, the gripper stays inflated. Two things
on the box, both generated here from the cell's wiring, close that gap (docs/safety.md):

1. **Run-state output actions** (URScript ``set_runstate_standard_digital_output_to_value``
   and its ``configurable`` twin): while no program runs on the box, every valve output
   is held at the level of its safe position. They are sent as a secondary program
   (``sec``), which runs beside whatever program runs and does not replace it.
2. **A program that runs only while the service's heartbeat comes.**
   - Cells with an arm: ur_rtde's control script is the box's program. Its RTDE watchdog
     (``RTDEControlInterface.setWatchdog``) stops the script when the worker stops kicking
     it, and the worker kicks only when the daemon's sample loop asks (``kick``). The
     script stops, the run-state actions vent.
   - Cells without an arm (I/O over Modbus only): ``watchdog_program`` is the box's
     program. A thread watches a general purpose register (Modbus 128-255) that the
     daemon increments; when it has not changed for ``timeout_s`` it sets every valve
     output to its safe level. Stopping this program also vents (run-state actions).

What neither covers: a box that loses power (the valves must then vent by their own
springs: normally-open vent paths), and a daemon that is alive but commands something
wrong while still sending its heartbeat (that is the supervisor's job).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Mapping

from fluidsense.common.errors import LinkLostError
from fluidsense.common.wiring import ValveWiring
from fluidsense.drivers.ur.box import BoxWatchdogConfig

log = logging.getLogger(__name__)

PROGRAM_NAME = "fluidsense_watchdog"
RUNSTATE_NAME = "fluidsense_runstate"
#: URScript run-state choices: the output's level whenever no program runs
RUNSTATE_LOW_WHEN_STOPPED, RUNSTATE_HIGH_WHEN_STOPPED = 1, 2


def _bank(output: int) -> tuple[str, int]:
    """UR numbering: outputs 0-7 are standard, 8-15 the configurable outputs 0-7."""
    return ("standard", output) if output < 8 else ("configurable", output - 8)


def safe_levels(valves: Mapping[str, ValveWiring], safe: Mapping[str, bool]) -> dict[int, bool]:
    """Digital output -> the electrical level of its valve's safe position."""
    return {valves[name].output: valves[name].level(open_) for name, open_ in safe.items() if name in valves}


def _runstate_lines(levels: Mapping[int, bool], indent: str) -> list[str]:
    lines = []
    for output, level in sorted(levels.items()):
        bank, n = _bank(output)
        state = RUNSTATE_HIGH_WHEN_STOPPED if level else RUNSTATE_LOW_WHEN_STOPPED
        lines.append(f"{indent}set_runstate_{bank}_digital_output_to_value({n}, {state})")
    return lines


def runstate_program(levels: Mapping[int, bool]) -> str:
    """A secondary program: every valve output at its safe level while no program runs."""
    body = _runstate_lines(levels, "  ")
    return "\n".join([f"sec {RUNSTATE_NAME}():", "  # fluidsense: valve outputs safe whenever no program runs",
                      *body, "end", ""])


def watchdog_lines(levels: Mapping[int, bool], heartbeat_register: int, timeout_s: float, handle: str) -> list[str]:
    """The watchdog itself, as statements inside a program's ``def`` (two spaces in): its
    constants, the run-state actions, ``fluidsense_vent`` and the thread that watches the
    heartbeat register, started as ``handle``. ``watchdog_program`` wraps it into the
    box's program; ``integrator_thread`` hands it to an integrator's own program."""
    if not 128 <= heartbeat_register <= 255:
        raise ValueError(f"heartbeat register {heartbeat_register}: a UR general purpose register is 128-255")
    vent = []
    for output, level in sorted(levels.items()):
        bank, n = _bank(output)
        vent.append(f"    set_{bank}_digital_out({n}, {'True' if level else 'False'})")
    return [
        f"  HEARTBEAT_REGISTER = {heartbeat_register}",
        f"  TIMEOUT_S = {timeout_s:.6g}",
        *_runstate_lines(levels, "  "),
        "  def fluidsense_vent():",
        *vent,
        "  end",
        "  thread fluidsense_heartbeat_watch():",
        "    last = read_port_register(HEARTBEAT_REGISTER)",
        "    quiet = 0",
        "    vented = False",
        "    while True:",
        "      beat = read_port_register(HEARTBEAT_REGISTER)",
        "      if beat != last:",
        "        last = beat",
        "        quiet = 0",
        "        vented = False",
        "      else:",
        "        quiet = quiet + get_steptime()",
        "      end",
        "      if quiet > TIMEOUT_S and not vented:",
        "        fluidsense_vent()",
        "        vented = True",
        "      end",
        "      sync()",
        "    end",
        "  end",
        f"  {handle} = run fluidsense_heartbeat_watch()",
    ]


def watchdog_program(levels: Mapping[int, bool], heartbeat_register: int, timeout_s: float) -> str:
    """The box's own program on cells without an arm: vents when the heartbeat register
    stops changing for ``timeout_s``, and again whenever it stops after coming back."""
    return "\n".join([
        f"def {PROGRAM_NAME}():",
        "  # fluidsense box watchdog (docs/safety.md): generated from the cell's wiring",
        *watchdog_lines(levels, heartbeat_register, timeout_s, "watch"),
        "  while True:",
        "    sync()",
        "  end",
        "end",
        "",
    ])


def integrator_thread(levels: Mapping[int, bool], heartbeat_register: int, timeout_s: float) -> str:
    """The same watchdog for a box whose one program is the integrator's (the arm's
    program): statements to paste into that program's ``def`` before its main loop. The
    daemon beats the register with ``driver.watchdog: {program: integrator}``."""
    return "\n".join([
        "  # fluidsense box watchdog thread (docs/safety.md), generated from the cell's wiring: paste these lines",
        "  # into your program's def, before its main loop. It vents the gripper when the daemon's heartbeat in",
        f"  # general purpose register {heartbeat_register} stops for {timeout_s:g} s; the daemon beats it with",
        f"  # driver.watchdog: {{program: integrator, heartbeat_register: {heartbeat_register}, "
        f"timeout_s: {timeout_s:g}}}",
        *watchdog_lines(levels, heartbeat_register, timeout_s, "fluidsense_watch"),
        "  # end of the fluidsense box watchdog thread",
        "",
    ])


def box_script(valves: Mapping[str, ValveWiring], safe: Mapping[str, bool], cfg: BoxWatchdogConfig,
               arm: bool) -> str:
    """What a cell installs on its box: with an arm (ur_rtde's script is the program, its
    RTDE watchdog stops it), the run-state actions; without one, the watchdog program."""
    levels = safe_levels(valves, safe)
    if arm:
        return runstate_program(levels)
    return watchdog_program(levels, cfg.heartbeat_register, cfg.timeout_s)


async def send_script(host: str, port: int, text: str, timeout_s: float = 2.0) -> None:
    """Send a URScript program to the box's script port (30003 on a UR)."""
    try:
        async with asyncio.timeout(timeout_s):
            _, writer = await asyncio.open_connection(host, port)
            try:
                writer.write(text.encode())
                await writer.drain()
            finally:
                writer.close()
                await writer.wait_closed()
    except (OSError, TimeoutError) as exc:
        raise LinkLostError(f"script port {host}:{port}: cannot send {text.split('(', 1)[0]!r}: {exc}") from exc
