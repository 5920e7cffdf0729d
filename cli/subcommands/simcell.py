"""``fluidsense simcell``: an emulated UR control box backed by the simulated plant."""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys

from fluidsense.common.errors import ConfigError

from ..options import add_scene_options, scene_from_args
from ._common import setup_logging

log = logging.getLogger(__name__)


def register(sub) -> None:
    p = sub.add_parser(
        "simcell", help="emulated UR control box backed by the simulated cell (for the ur and modbus drivers)",
        description="Serve a UR control box (RTDE 30004, dashboard 29999, script 30003, Modbus) on the host of a "
        "cell config whose driver is ur or modbus, with the config's wiring between its I/O and the simulated "
        "plant of the config's profile, and a simulated arm. Prints a line starting with 'ready' once every "
        "port listens; SIGTERM or Ctrl-C stops it. Run the daemon with the same config against it.")
    p.add_argument("--config", "-c", required=True, help="cell config with driver kind ur or modbus")
    p.add_argument("--seed", type=int, default=1, help="seed of the simulated cell (default 1)")
    add_scene_options(p)
    p.add_argument("--modbus-port", type=int, help="Modbus port (default: the config's for kind modbus, else 5020)")
    p.add_argument("--rt-priority", type=int, default=30, metavar="N",
                   help="SCHED_FIFO priority of the box when permitted, 0 for normal scheduling (default 30: a "
                   "real box answers from its own CPU; here it shares two with the daemon; below the sampler's 40)")
    p.add_argument("--log-level", choices=["DEBUG", "INFO", "WARNING", "ERROR"], default="WARNING")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from fluidsense.controller.config import load_cell_config
    from fluidsense.drivers.registry import DriverEntry, SimDriverConfig, kinds
    from fluidsense.simulator.controlbox.__main__ import main_async
    from fluidsense.simulator.controlbox.config import ControlBoxConfig
    from fluidsense.simulator.controlbox.plant import PlantModel

    cfg = load_cell_config(args.config)
    reached = cfg.driver.control_box()  # the box this config's driver reaches
    if reached is None:
        raise ConfigError(f"{args.config}: driver.kind: simcell emulates the control box of a "
                          f"{' or '.join(kinds(DriverEntry.control_box))} driver, this config's driver is "
                          f"{cfg.driver.kind!r}")
    setup_logging(args.log_level)
    logging.getLogger("pymodbus").setLevel(logging.WARNING)
    modbus_port = args.modbus_port or reached.modbus_port or 5020
    # the box refreshes its I/O at its generation's control rate; a Modbus I/O module's
    # registers are served at the polled rate (the slowest its data sheet may promise)
    io_module = reached.controller == "io-module"
    box = ControlBoxConfig(host=reached.host, modbus_port=modbus_port, analog=reached.analog,
                           controller="e-series" if io_module else reached.controller,
                           io_refresh_hz=reached.rate_hz if io_module else None)
    sim = SimDriverConfig(clock="realtime", rate_hz=1000.0, block_size=1, seed=args.seed,
                          **({"scene": s} if (s := scene_from_args(args)) is not None else {}))
    model = PlantModel(cfg.profile.hardware, reached.wiring, sim)
    if args.rt_priority:
        from fluidsense.drivers.sampler.realtime import set_fifo

        result = set_fifo(args.rt_priority)
        log.log(logging.INFO if result["applied"] else logging.WARNING, "simcell scheduling: %s", result["detail"])
    try:
        asyncio.run(main_async(box, model, reached.sim_control_port))
    except KeyboardInterrupt:
        pass
    sys.stdout.flush()
    return 0
