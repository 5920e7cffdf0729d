"""The ``fluidsense`` command line."""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import sys
from typing import Any

from drivers.errors import FluidsenseError

from . import app
from .monitor import monitor, send_command

log = logging.getLogger("fluidsense")

DEMO_DIAMETERS: list[float | None] = [None, 20, 40, 60, 80, 100]


def _setup_logging(level: str, quiet: bool = False) -> None:
    logging.basicConfig(level=logging.WARNING if quiet else getattr(logging, level),
                        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s", stream=sys.stderr)


# ------------------------------------------------------------------ commands
def cmd_run(args: argparse.Namespace) -> int:
    overrides = {"driver": {"clock": "virtual"}} if args.virtual else None
    cfg = app.load(args.config, overrides)
    _setup_logging(args.log_level or cfg.log_level)
    return asyncio.run(app.run_daemon(cfg))


def cmd_demo(args: argparse.Namespace) -> int:
    from tasks.size_survey import size_survey

    overrides: dict[str, Any] = {"driver": {"clock": "virtual", "seed": args.seed}}
    cfg = app.load(args.config, overrides)
    _setup_logging(cfg.log_level, quiet=True)
    if cfg.driver.kind != "sim":
        raise FluidsenseError("the demo runs on the simulated cell: use a config with driver: sim")

    def progress(line: str) -> None:
        if not args.json:
            print(f"  {line}", file=sys.stderr, flush=True)

    async def job():
        async with app.controller(cfg) as ctrl:
            return await size_survey(ctrl, DEMO_DIAMETERS, cycles=args.cycles, drop_first=1,
                                     progress=progress)

    if not args.json:
        w = cfg.profile.sequence.windows[0]
        print(f"fluidsense demo: {cfg.profile.name}, tank {cfg.profile.circuit.tank_l} L at "
              f"{cfg.profile.sequence.p0_kpa} kPa, {args.cycles} cycles per object (first dropped), "
              f"P_eq over {w.start_s:g}-{w.end_s:g} s after opening, virtual time, seed {args.seed}",
              file=sys.stderr)
    res = asyncio.run(job())
    out = res.to_dict()
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    print()
    print(f"{'object':>12} | {'P_eq (kPa)':>10} | {'sd (kPa)':>8} | cycles")
    print(f"{'-' * 12}-+-{'-' * 10}-+-{'-' * 8}-+-------")
    for p in out["points"]:
        name = "nothing" if p["diameter_mm"] is None else f"D {p['diameter_mm']:g} mm"
        print(f"{name:>12} | {p['p_eq_kpa']:10.3f} | {p['p_sd_kpa']:8.3f} | {p['cycles']}")
    print()
    print(f"linear fit over D >= {out['fit']['min_diameter_mm']:g} mm: P_eq = "
          f"{out['fit']['intercept_kpa']:.3f} kPa + {out['slope_kpa_per_mm']:.4f} kPa/mm * D   "
          f"(r^2 = {out['r2']:.4f}; paper: about 0.04 kPa/mm)")
    print(f"{out['cycles_run']} cycles, {out['virtual_s']:.0f} s of sample time in {out['wall_s']:.2f} s "
          f"wall ({out['speedup']:.0f}x real time, {out['wall_ms_per_cycle']:.0f} ms per cycle)")
    return 0


def cmd_monitor(args: argparse.Namespace) -> int:
    endpoint = args.endpoint
    if endpoint is None:
        endpoint = app.load(args.config).publisher.pub
    topics = args.topic or ["state", "cycle", "heartbeat", "fault", "task", "log"]
    if args.all:
        topics = [""]
    return monitor(endpoint, topics, args.count, args.timeout, args.json)


def cmd_cmd(args: argparse.Namespace) -> int:
    endpoint = args.endpoint or app.load(args.config).publisher.cmd
    try:
        request = json.loads(args.request)
    except json.JSONDecodeError:
        request = {"cmd": args.request}
    reply = send_command(endpoint, request, args.timeout)
    print(json.dumps(reply, indent=2))
    return 0 if reply.get("ok") else 1


# -------------------------------------------------------------------- parser
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fluidsense",
        description="Closed-loop controller for soft pneumatic grippers with retrofit fluidic sensing.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("run", help="run the controller daemon",
                       description="Run the daemon: sample, sequence cycles on command, publish on ZeroMQ. "
                       "Ctrl-C or SIGTERM vents the actuator and exits.")
    p.add_argument("--config", "-c", help="cell config YAML (default: config/cell-sim.yaml)")
    p.add_argument("--virtual", action="store_true",
                   help="simulated cell in virtual time (sample time only advances while a cycle runs)")
    p.add_argument("--log-level", choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("demo", help="size sensing on the simulated gripper (paper Fig. 1f)",
                       description="Grip nothing and cylinders of D = 20, 40, 60, 80, 100 mm in virtual time, "
                       "6 cycles each (the last 5 used), P_eq over 4-5 s after opening; print P_eq per D "
                       "and the linear fit.")
    p.add_argument("--config", "-c", help="cell config YAML with driver: sim (default: config/cell-sim.yaml)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--seed", type=int, default=1, help="random seed of the simulated cell (default 1)")
    p.add_argument("--cycles", type=int, default=6, help="cycles per object, first dropped (default 6)")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("monitor", help="show live state and results from a running daemon",
                       description="Subscribe to the daemon's PUB socket and print state transitions, "
                       "cycle results, heartbeats and faults.")
    p.add_argument("--config", "-c", help="cell config naming the endpoint (default: config/cell-sim.yaml)")
    p.add_argument("--endpoint", help="PUB endpoint, e.g. tcp://127.0.0.1:5560 (overrides --config)")
    p.add_argument("--topic", action="append", help="topic to show (repeatable; default: all but pressure)")
    p.add_argument("--all", action="store_true", help="every topic, pressure included")
    p.add_argument("--count", type=int, help="exit after this many messages")
    p.add_argument("--timeout", type=float, help="exit after this many seconds without a message")
    p.add_argument("--json", action="store_true", help="print raw JSON messages")
    p.set_defaults(func=cmd_monitor)

    p = sub.add_parser("cmd", help="send one request to the command socket",
                       description="Send a request and print the reply, e.g. "
                       "fluidsense cmd status, fluidsense cmd '{\"cmd\": \"cycle\", \"store_reference\": true}'.")
    p.add_argument("request", help="a command name (status, cycle, abort, reset, shutdown) or a JSON object")
    p.add_argument("--config", "-c", help="cell config naming the endpoint (default: config/cell-sim.yaml)")
    p.add_argument("--endpoint", help="command endpoint, e.g. tcp://127.0.0.1:5561")
    p.add_argument("--timeout", type=float, default=5.0)
    p.set_defaults(func=cmd_cmd)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except FluidsenseError as exc:
        print(f"fluidsense: error: {exc}", file=sys.stderr)
        return 2
    except TimeoutError as exc:
        print(f"fluidsense: error: {exc}", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
