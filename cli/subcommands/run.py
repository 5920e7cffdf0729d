"""``fluidsense run``: the daemon."""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path

from fluidsense.common.exitcodes import EXIT_BAD_INPUT

from ._common import setup_logging


def register(sub) -> None:
    p = sub.add_parser("run", help="run the controller daemon",
                       description="Run the daemon: sample, sequence cycles on command, publish on ZeroMQ. "
                       "Ctrl-C or SIGTERM vents the actuator and exits.")
    p.add_argument("--config", "-c", help="cell config YAML (default: config/cell-sim.yaml)")
    p.add_argument("--virtual", action="store_true",
                   help="simulated cell in virtual time (sample time only advances while a cycle runs)")
    p.add_argument("--log-level", choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    rec = p.add_mutually_exclusive_group()
    rec.add_argument("--record", metavar="DIR", help="record to this directory (default: the config's "
                     "recording.dir, runs/ unless set; docs/recording.md)")
    rec.add_argument("--no-record", action="store_true", help="do not record")
    p.add_argument("--live", metavar="[HOST:]PORT", help="serve the live view to Foxglove (WebSocket) on this "
                   "port, on loopback unless HOST is given (docs/recording.md; the config's live: section)")
    p.add_argument("--tasks-dir", help="directory of task files the command socket may start "
                   "(default: config/tasks)")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from fluidsense.daemon import app

    overrides = {"driver": {"clock": "virtual"}} if args.virtual else {}
    if args.record or args.no_record:
        overrides["recording"] = {"enabled": False} if args.no_record else {"enabled": True, "dir": args.record}
    if args.live is not None:
        from fluidsense.controller.telemetry.live import parse_listen

        try:
            host, port = parse_listen(args.live)
        except ValueError as exc:
            print(f"fluidsense run: --live: {exc}", file=sys.stderr)
            return EXIT_BAD_INPUT
        overrides["live"] = {"enabled": True, "host": host, "port": port}
    cfg = app.load(args.config, overrides)
    setup_logging(args.log_level or cfg.log_level)
    return asyncio.run(app.run_daemon(cfg, Path(args.tasks_dir) if args.tasks_dir else None, own_process=True))
