"""``python -m fluidsense.simulator.controlbox``: an emulated UR control box in this process.

Prints one line starting with ``ready`` on stdout once every port listens, then answers
sim control commands (JSON lines on stdin, see simcontrol.py) on stdout. Logs go to
stderr. SIGTERM or SIGINT closes every port and exits 0; a port that cannot be bound
exits 2 before ``ready``.
"""

from __future__ import annotations

import argparse
import asyncio
import importlib
import json
import logging
import os
import signal
import stat
import sys
from collections.abc import Callable

from fluidsense.common.errors import ConfigError, DriverError, FluidsenseError
from fluidsense.simulator.controlbox import simcontrol
from fluidsense.simulator.controlbox.config import AnalogScale, ControlBoxConfig
from fluidsense.simulator.controlbox.emulator import Emulator
from fluidsense.simulator.controlbox.kinematic import KinematicModel
from fluidsense.simulator.controlbox.model import ControlBoxModel
from pydantic import ValidationError

log = logging.getLogger("fluidsense.simulator.controlbox")


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m fluidsense.simulator.controlbox", description=__doc__.splitlines()[0])
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--rtde-port", type=int, default=30004)
    p.add_argument("--dashboard-port", type=int, default=29999)
    p.add_argument("--script-port", type=int, default=30003)
    p.add_argument("--modbus-port", type=int, default=502)
    p.add_argument("--model", default=None, metavar="MODULE:FACTORY",
                   help="callable returning a ControlBoxModel (default: a KinematicModel)")
    p.add_argument("--controller", choices=["e-series", "cb3"], default="e-series",
                   help="generation: the control rate, at which RTDE sends at most and the I/O registers refresh "
                   "(e-series 500 Hz, cb3 125 Hz; default e-series)")
    p.add_argument("--unlock-delay", type=float, default=5.0,
                   help="seconds after a protective stop before the dashboard may unlock it")
    p.add_argument("--analog-voltage-range", type=float, nargs=2, default=(0.0, 10.0), metavar=("LOW_V", "HIGH_V"))
    p.add_argument("--analog-current-range", type=float, nargs=2, default=(4.0, 20.0), metavar=("LOW_MA", "HIGH_MA"))
    p.add_argument("--no-remote-control", action="store_true", help="dashboard says the robot is in local control")
    p.add_argument("--log-level", default="INFO")
    return p.parse_args(argv)


def make_config(args: argparse.Namespace) -> ControlBoxConfig:
    try:
        return ControlBoxConfig(
            host=args.host, rtde_port=args.rtde_port, dashboard_port=args.dashboard_port,
            script_port=args.script_port, modbus_port=args.modbus_port, controller=args.controller,
            unlock_delay_s=args.unlock_delay, remote_control=not args.no_remote_control,
            analog=AnalogScale(voltage_v=tuple(args.analog_voltage_range),
                               current_ma=tuple(args.analog_current_range)))
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors())
        raise ConfigError(f"control box emulator: {problems}") from exc


def load_model(spec: str | None) -> ControlBoxModel:
    if spec is None:
        return KinematicModel()
    module_name, _, attr = spec.partition(":")
    if not module_name or not attr:
        raise ConfigError(f"--model must be MODULE:FACTORY, got {spec!r}")
    try:
        factory: Callable[[], ControlBoxModel] = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"--model {spec}: {exc}") from exc
    model = factory()
    if not isinstance(model, ControlBoxModel):
        raise ConfigError(f"--model {spec} returned {type(model).__name__}, not a ControlBoxModel")
    return model


async def serve_sim_control(emulator: Emulator) -> None:
    """Answer JSON commands on stdin until it closes."""
    if not _pollable(sys.stdin):
        log.info("stdin is not a pipe or terminal: no sim control channel")
        return
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader()
    await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
    while line := await reader.readline():
        if line.strip():
            reply = simcontrol.handle(emulator.box, line.decode(errors="replace"))
            sys.stdout.write(json.dumps(reply, default=float) + "\n")
            sys.stdout.flush()


def _pollable(stream) -> bool:
    """epoll can watch pipes, sockets and terminals, not files or /dev/null."""
    try:
        mode = os.fstat(stream.fileno()).st_mode
    except (OSError, ValueError):
        return False
    return stat.S_ISFIFO(mode) or stat.S_ISSOCK(mode) or stream.isatty()


async def main_async(config: ControlBoxConfig, model: ControlBoxModel, sim_control_port: int | None = None) -> None:
    emulator = Emulator(config, model)
    await emulator.start()
    tcp_control = None
    if sim_control_port is not None:
        try:
            tcp_control = await simcontrol.serve_tcp(emulator.box, config.host, sim_control_port)
        except OSError as exc:
            await emulator.close()
            raise DriverError(f"sim control cannot listen on {config.host}:{sim_control_port}: {exc}") from exc
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, emulator.stop)
    sim = f" sim_control={sim_control_port}" if tcp_control is not None else ""
    print(f"ready host={config.host} rtde={config.rtde_port} dashboard={config.dashboard_port} "
          f"script={config.script_port} modbus={config.modbus_port}{sim}", flush=True)
    control = asyncio.create_task(serve_sim_control(emulator))
    try:
        await emulator.run()
    finally:
        control.cancel()
        if tcp_control is not None:
            tcp_control.close()
        await emulator.close()
        log.info("control box emulator stopped")


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=args.log_level.upper(), stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    logging.getLogger("pymodbus").setLevel(logging.WARNING)
    try:
        config = make_config(args)
        model = load_model(args.model)
        asyncio.run(main_async(config, model))
    except FluidsenseError as exc:
        log.error("%s", exc)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
