"""``fluidsense task run FILE``: run a closed-loop task."""

from __future__ import annotations

import argparse
import json

from fluidsense.common import stopsignals
from fluidsense.common.errors import ConfigError, JobStopped
from fluidsense.common.exitcodes import EXIT_FAULT, EXIT_OK

from ._common import print_signal_stop, print_stopped, setup_logging


def register(sub) -> None:
    p = sub.add_parser("task", help="closed-loop tasks: sorting, tomato picking, ripeness",
                       description="Run a task file (config/tasks/*.yaml) on the cell it names.")
    tasks = p.add_subparsers(dest="task_command", required=True, metavar="ACTION")
    r = tasks.add_parser("run", help="run a task file", description="Run a task and print its summary. On a "
                         "simulated cell the summary scores itself against the known truth.")
    r.add_argument("file", help="task file, e.g. config/tasks/sorting.yaml, or a shipped task's name: sorting, "
                                    "picking, ripeness")
    r.add_argument("--config", "-c", help="cell config to use instead of the one the task file names")
    r.add_argument("--order", help="sorting on a simulated cell: diameters (mm) in the input slots, e.g. 100,40,60,80")
    r.add_argument("--seed", type=int, help="seed of a simulated cell")
    r.add_argument("--publish", action="store_true", help="publish progress on the cell's ZeroMQ PUB socket")
    r.add_argument("--json", action="store_true", help="print the summary as JSON")
    r.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from fluidsense.daemon import app
    from fluidsense.tasks.config import cell_path, load_task, task_file
    from fluidsense.tasks.runner import run_task

    path = task_file(args.file)
    task = load_task(path)
    overrides = {"driver": {"seed": args.seed}} if args.seed is not None else None
    cfg = app.load(args.config or cell_path(path, task), overrides)
    setup_logging(cfg.log_level, quiet=args.json)
    order = None
    if args.order:
        try:
            order = [float(x) for x in args.order.split(",")]
        except ValueError:
            raise ConfigError(f"--order: expected comma-separated diameters, got {args.order!r}") from None

    valves = []  # the cell's valve bank once connected: where a stop left them

    async def job():
        async with app.controller(cfg, publish=args.publish, own_process=True) as ctrl:
            valves.append(ctrl.backend.valves)
            return await run_task(ctrl.task_port, task, order_mm=order)

    try:
        summary = stopsignals.run(job())
    except JobStopped as exc:
        print_stopped(exc, args.json)
        return EXIT_FAULT
    except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM, SIGHUP: after the controller vented
        return print_signal_stop(stopsignals.interruption(exc), f"task {task.task}", valves[0] if valves else None)
    print(json.dumps(summary, indent=2, default=float))
    return EXIT_OK if summary.get("success", True) is not False else EXIT_FAULT
