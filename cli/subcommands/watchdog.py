"""``fluidsense watchdog``: the URScript the driver installs on a UR box so that the box
vents the gripper by itself when the service stops (docs/safety.md); for a box whose one
program is the integrator's (``watchdog: null`` or ``program: integrator``, no arm), the
same watchdog as a thread to paste into that program."""

from __future__ import annotations

import argparse
import asyncio
import sys


def register(sub) -> None:
    p = sub.add_parser(
        "watchdog", help="print (or send) the control box's vent watchdog for a cell",
        description="Print the URScript that the ur and modbus drivers send to the box at every connection: the "
        "run-state output actions (every valve output at its safe level while no program runs) and, on a cell "
        "without an arm, the watchdog program that vents when the daemon's heartbeat register stops. --install "
        "sends it to the box's script port now (a def program replaces the program that runs there). A cell "
        "without an arm whose box runs the integrator's own program (driver.watchdog: null or {program: "
        "integrator}): the same watchdog as a thread to paste into that program, and on stderr the setting that "
        "makes the daemon beat its register.")
    p.add_argument("--config", "-c", required=True, help="cell config with driver kind ur or modbus")
    p.add_argument("--install", action="store_true", help="send it to the box's script port")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from fluidsense.common.errors import ConfigError
    from fluidsense.controller.config import load_cell_config
    from fluidsense.drivers.registry import DriverEntry, kinds
    from fluidsense.drivers.ur.box import BoxWatchdogConfig
    from fluidsense.drivers.ur.watchdog import box_script, integrator_thread, safe_levels, send_script

    cfg = load_cell_config(args.config)
    box = cfg.driver.control_box()
    if box is None:
        raise ConfigError(f"{args.config}: driver.kind: the box watchdog is for a UR control box "
                          f"({' or '.join(kinds(DriverEntry.control_box))}), this config's driver is "
                          f"{cfg.driver.kind!r}")
    levels = safe_levels(box.wiring.valves, cfg.profile.hardware.circuit.safe_valves)
    if not box.arm and (box.watchdog is None or box.watchdog.program == "integrator"):
        dog = box.watchdog or BoxWatchdogConfig()
        if args.install:
            raise ConfigError(f"{args.config}: driver.watchdog: the box's program is the integrator's: the thread "
                              "goes into that program, --install would replace it")
        print(integrator_thread(levels, dog.heartbeat_register, dog.timeout_s), end="")
        if box.watchdog is None:
            sys.stderr.write(f"fluidsense watchdog: {args.config} has driver.watchdog: null: once the thread runs in "
                             f"the box's program, set driver.watchdog: {{program: integrator}} so that the daemon "
                             f"beats register {dog.heartbeat_register}; until then nothing vents the gripper when "
                             "the link or the daemon dies (fluidsense check says for how long)\n")
        return 0
    if box.watchdog is None:
        raise ConfigError(f"{args.config}: driver.watchdog: null: this cell has no box-side watchdog (with an arm, "
                          "ur_rtde's control script carries it: delete `watchdog: null`)")
    script = box_script(box.wiring.valves, cfg.profile.hardware.circuit.safe_valves, box.watchdog, box.arm)
    print(script, end="")
    if args.install:
        asyncio.run(send_script(box.host, box.watchdog.script_port, script))
    return 0
