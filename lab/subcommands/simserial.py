"""``python -m lab simserial``: the serial streamer's firmware behind a pty on the simulated
cell, for the ``serial`` driver: the host board, or the AVR image run by simavr (``--board avr``)."""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import os
import signal
import sys
import threading

from fluidsense.cli.options import add_scene_options, scene_from_args
from fluidsense.cli.subcommands._common import setup_logging
from fluidsense.common.errors import ConfigError

log = logging.getLogger(__name__)


def register(sub) -> None:
    p = sub.add_parser(
        "simserial", help="the serial streamer's firmware on a pty, fed by the simulated cell (for the serial driver)",
        description="Build and start a board behind a pseudo-terminal linked at the config's driver.port, with the "
        "simulated cell of the config's profile on its pins as driver.wiring says: the firmware's host board "
        "(firmware/boards/host: the protocol code as a Linux process) or, with --board avr, the AVR image itself "
        "executed by simavr as an ATmega328P at 16 MHz (firmware/boards/simavr). Prints 'ready PORT' once the link "
        "exists; SIGTERM or Ctrl-C stops it and prints 'stats {...}'. Sim control: JSON lines on stdin (and TCP on "
        "driver.sim_control_port): state, scene, truth, reset (the device resets as its reset pin would), stall "
        "(avr: the firmware's main loop stops; its hardware watchdog resets it).")
    p.add_argument("--board", choices=["host", "avr"], default="host",
                   help="host: the core compiled for Linux (default); avr: the AVR image (build/avr/fluidsense.elf) "
                   "in simavr, which needs Debian's gcc-avr, avr-libc, simavr and libsimavr-dev")
    p.add_argument("--config", "-c", required=True, help="cell config with driver kind serial")
    p.add_argument("--seed", type=int, default=1, help="seed of the simulated cell (default 1)")
    add_scene_options(p)
    p.add_argument("--rt-priority", type=int, default=30, metavar="N",
                   help="SCHED_FIFO priority of the board when permitted (the plant gets N-1), 0 for normal "
                   "scheduling (default 30, above the daemon's sample loop: a microcontroller runs on its own CPU; "
                   "here it shares two, and the simulated AVR needs a quarter to a third of one to keep time)")
    p.add_argument("--adc-wait-us", type=int, default=200, metavar="US",
                   help="how long after a tick the board waits for the plant's inputs before it samples the newest "
                   "it has (default 200: the AVR's two conversions take 208 us)")
    p.add_argument("--log-level", choices=["DEBUG", "INFO", "WARNING", "ERROR"], default="WARNING")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from fluidsense.controller.config import load_cell_config
    from fluidsense.drivers.registry import SimDriverConfig
    from fluidsense.drivers.serial.config import SerialDriverConfig

    from ..serialboard import AVR_IMAGE, SerialPlant, SimSerial, build_board

    cfg = load_cell_config(args.config)
    driver = cfg.driver
    if not isinstance(driver, SerialDriverConfig):  # the one device this emulates
        raise ConfigError(f"{args.config}: driver.kind: simserial emulates the device of a serial driver, this "
                          f"config's driver is {driver.kind!r}")
    setup_logging(args.log_level)
    board = build_board(args.board)
    sim = SimDriverConfig(clock="realtime", rate_hz=float(driver.rate_hz), block_size=1, seed=args.seed,
                          **({"scene": s} if (s := scene_from_args(args)) is not None else {}))
    plant = SerialPlant(cfg.profile.hardware, driver, sim)
    argv = [str(board), "--link", driver.port, "--rt", str(args.rt_priority), "--adc-wait-us", str(args.adc_wait_us)]
    if args.board == "avr":  # the image says its ADC's bits itself; its reference is the board's AVcc
        argv += ["--elf", str(AVR_IMAGE), "--vref-mv", str(round(driver.adc.reference_v * 1000))]
    else:
        argv += ["--adc-bits", str(driver.adc.bits)]
    if args.rt_priority > 1:
        from fluidsense.drivers.sampler.realtime import set_fifo

        result = set_fifo(args.rt_priority - 1)
        log.log(logging.INFO if result["applied"] else logging.WARNING, "simserial scheduling: %s", result["detail"])
    try:
        return asyncio.run(_serve(SimSerial(plant, argv, args.board), driver))
    except KeyboardInterrupt:
        return 0


async def _serve(sim, driver) -> int:
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    await sim.start()
    ended = asyncio.create_task(sim.done.wait())
    ready = asyncio.create_task(sim.ready.wait())
    await asyncio.wait([ended, ready], timeout=30, return_when=asyncio.FIRST_COMPLETED)
    if not sim.ready.is_set():
        code = await sim.stop()
        print(f"fluidsense: error: the {sim.board} board did not start (exit {code})", file=sys.stderr)
        return 2 if code == 2 else 1
    print(f"ready {driver.port}", flush=True)
    server = None
    if driver.sim_control_port is not None:
        server = await asyncio.start_server(lambda r, w: _client(sim, r, w), "127.0.0.1", driver.sim_control_port)
    # a thread: stdin may be a file or /dev/null, which epoll refuses
    threading.Thread(target=_stdin, args=(sim, loop), name="sim-control-stdin", daemon=True).start()
    await asyncio.wait([ended, asyncio.create_task(stop.wait())], return_when=asyncio.FIRST_COMPLETED)
    if server is not None:
        server.close()
    board_ended = sim.done.is_set()
    code = await sim.stop()
    print("stats " + json.dumps({"board": sim.board_stats, "plant": {"ticks": sim.plant.ticks,
                                 "vents": sim.plant.vents, "resets": sim.plant.resets,
                                 "reset_causes": sim.plant.reset_causes}}), flush=True)
    if board_ended:
        print(f"fluidsense: error: the {sim.board} board ended by itself (exit {code})", file=sys.stderr)
        return 1
    return 0


def _stdin(sim, loop: asyncio.AbstractEventLoop) -> None:
    # the raw descriptor: a daemon thread blocked in sys.stdin's buffer holds its lock, and the
    # interpreter aborts at exit waiting for it
    pending = b""
    while data := os.read(sys.stdin.fileno(), 1 << 16):
        *lines, pending = (pending + data).split(b"\n")
        for line in lines:
            if line.strip():
                loop.call_soon_threadsafe(_answer, sim, line)


def _answer(sim, line: bytes) -> None:
    print(json.dumps(sim.control(line), default=float), flush=True)


async def _client(sim, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    try:
        while line := await reader.readline():
            writer.write((json.dumps(sim.control(line), default=float) + "\n").encode())
            await writer.drain()
    except (ConnectionError, asyncio.IncompleteReadError):
        pass
    finally:
        writer.close()
