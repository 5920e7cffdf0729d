"""``fluidsense calibrate`` and ``fluidsense sense``."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from pathlib import Path

from fluidsense.common.errors import CommandError, ConfigError, JobStopped
from fluidsense.common import stopsignals
from fluidsense.common.exitcodes import EXIT_FAULT, EXIT_OK
from fluidsense.common.names import FEATURES, FIT_DEGREE

from ..options import add_cell_options, add_scene_options, cell_config, scene_from_args
from ._common import print_signal_stop, print_stopped, setup_logging


def register(sub) -> None:
    p = sub.add_parser("calibrate", help="run calibration cycles over known targets and fit a curve",
                       description="Run N cycles per target value (the first dropped, as in the paper), fit the "
                       "feature against the target and save the calibration. Defaults come from the profile's "
                       "calibration section (the paper's protocol).")
    add_cell_options(p)
    add_scene_options(p)
    p.add_argument("--target", help="scene field to vary (default: the profile's)")
    p.add_argument("--values", help="comma-separated target values, e.g. 0,5,10,15")
    p.add_argument("--feature", choices=list(FEATURES), help="what to fit (default: the profile's)")
    p.add_argument("--fit", choices=list(FIT_DEGREE), help="curve (default: linear)")
    p.add_argument("--cycles", type=int, help="cycles per target (default: the profile's)")
    p.add_argument("--drop-first", type=int, help="cycles dropped per target (default: the profile's)")
    p.add_argument("--free-cycles", type=int, help="cycles with nothing there, first: what 'no object' reads "
                   "(default: as many as per target; 0 = none, sense then cannot say 'no object' from P_eq)")
    p.add_argument("--out", "-o", default="calibration.json", help="calibration file (default calibration.json)")
    p.add_argument("--json", action="store_true", help="print the calibration as JSON")
    p.add_argument("--resume", action="store_true", help="continue a run that stopped: the cycles in OUT.cycles.jsonl "
                   "(saved as each one finishes) are not run again")
    _operator_options(p)
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("sense", help="measure and invert a calibration",
                       description="Run cycles on the current (or given) scene, average the feature and invert "
                       "the calibration: the estimate with a 95 % interval from the fit's residuals and noise.")
    p.add_argument("--calibration", "-k", required=True, help="calibration file from fluidsense calibrate")
    add_cell_options(p)
    add_scene_options(p)
    p.add_argument("--cycles", type=int, default=1, help="cycles to average (default 1)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    _operator_options(p)
    p.set_defaults(func=cmd_sense)


def _operator_options(p) -> None:
    who = p.add_mutually_exclusive_group()
    who.add_argument("--targets-from", metavar="FILE", help="real cell, scripted: read one line per placed target "
                     "(its value) from FILE, e.g. a FIFO another program writes, instead of asking at the terminal")
    who.add_argument("--yes", action="store_true", help="real cell: do not wait for the operator (the targets are "
                     "placed in the listed order by other means)")


_PLACES = {
    "none": "clear the actuator: nothing may touch it",
    "cylinder": "place the {diameter_mm:g} mm cylinder between the fingers",
    "rectangle": "place the {length_mm:g} x {width_mm:g} mm block between the fingers",
    "plate": "set the plate {height_mm:g} mm below the actuator's tip",
    "sample": "put the {material} sample under the suction cup",
    "stopper": "set the stopper at {angle_deg:g} degrees",
    "wall": "set the wall {distance_mm:g} mm from the actuator's tip",
}


def place_text(scene) -> str:
    """What the operator is asked to do, in words."""
    fields = scene.model_dump()
    try:
        return _PLACES[scene.kind].format(**fields)
    except (KeyError, ValueError):
        return f"set up the {scene.kind} scene with " + ", ".join(f"{k} = {v}" for k, v in fields.items() if k != "kind")


class Operator:
    """On a real cell somebody places each target: a person at a terminal (asked in words,
    the progress bar out of the way), a program writing one line per placed target to
    ``--targets-from`` (a file or a FIFO: the line must name the value asked for), or
    nobody (``--yes``: the targets are placed in the listed order by other means)."""

    def __init__(self, target: str, targets_from: str | None, yes: bool, job: str = "calibrating"):
        self.target, self.yes = target, yes
        self.lines = None
        if targets_from is not None:
            self.lines = open(targets_from, encoding="utf-8")  # noqa: SIM115 - read line by line through the run
        elif not yes and not sys.stdin.isatty():
            raise CommandError(f"{job} a real cell asks the operator to place each target, and stdin is not a "
                               "terminal: run it in one, or pass --targets-from FILE (one line per placed target) "
                               "or --yes (targets placed in the listed order by other means)")
        self.bar = None

    async def place(self, scene) -> None:
        text = place_text(scene)
        if self.yes:
            self._say(f"next: {text} (--yes: not waiting)")
            return
        if self.lines is not None:
            line = await asyncio.get_running_loop().run_in_executor(None, self.lines.readline)
            wanted = getattr(scene, self.target, None)
            if not line or (scene.kind != "none" and _number(line) != wanted):
                raise CommandError(f"--targets-from: expected a line with {wanted} for '{text}', got {line.strip()!r}")
            self._say(f"placed: {text}")
            return
        self._say(f">>> {text}, then press Enter")
        line = await asyncio.get_running_loop().run_in_executor(None, sys.stdin.readline)
        if not line:
            raise CommandError("stdin closed while waiting for the operator")

    def _say(self, text: str) -> None:
        if self.bar is not None:
            self.bar.clear()
        print(text, file=sys.stderr, flush=True)
        if self.bar is not None:
            self.bar.refresh()

    def close(self) -> None:
        if self.lines is not None:
            self.lines.close()


def _number(line: str) -> float | None:
    try:
        return float(line.strip())
    except ValueError:
        return None


def cmd_calibrate(args: argparse.Namespace) -> int:
    from fluidsense.daemon import app
    from fluidsense.tasks.calibrate import calibrate
    from fluidsense.tasks.journal import CycleJournal, journal_path
    from tqdm import tqdm

    cfg = cell_config(args)
    setup_logging(cfg.log_level, quiet=True)
    plan = cfg.profile.calibration
    base = plan.scene if plan is not None else None
    scene = scene_from_args(args, base)
    target = args.target or (plan.target if plan is not None else None)
    if scene is None or target is None:
        raise ConfigError("the profile has no calibration section: give --scene, --target and --values")
    values = [float(v) for v in args.values.split(",")] if args.values else (plan.values if plan else None)
    if not values:
        raise ConfigError("give --values")
    feature = args.feature or (plan.feature if plan else "p_eq")
    fit = args.fit or (plan.fit if plan else "linear")
    cycles = args.cycles or (plan.cycles if plan else 8)
    drop = args.drop_first if args.drop_first is not None else (plan.drop_first if plan else 1)
    if drop >= cycles:
        raise ConfigError(f"--drop-first {drop} leaves no cycle of --cycles {cycles}")
    free = cycles if args.free_cycles is None else args.free_cycles
    if free < 0 or (free and drop >= free):
        raise ConfigError(f"--free-cycles {free}: give 0 or more than --drop-first {drop}")
    operator = Operator(target, args.targets_from, args.yes) if cfg.driver.needs_operator() else None
    journal = CycleJournal.open(journal_path(args.out), {
        "profile": cfg.profile.name, "scene": scene.model_dump(), "target": target, "values": values,
        "feature": feature, "fit": fit, "cycles": cycles, "drop_first": drop, "free_cycles": free},
        resume=args.resume)
    total = len(values) * cycles + free  # the free (nothing there) cycles count as the bar counts them
    if journal.entries:
        print(f"resuming: {len(journal.entries)} of {total} cycles done ({journal.path})", file=sys.stderr)
    valves = []  # the cell's valve bank once connected: where a stop left them

    async def job():
        async with app.controller(cfg, own_process=True) as ctrl:
            valves.append(ctrl.backend.valves)
            with tqdm(total=total, initial=len(journal.entries), desc=f"calibrating {cfg.profile.name}",
                      unit="cycle", file=sys.stderr, disable=args.json) as bar:
                if operator is not None:
                    operator.bar = bar
                return await calibrate(ctrl.task_port, scene, target, values, feature=feature, fit=fit, cycles=cycles,
                                       drop_first=drop, place=operator.place if operator else None,
                                       progress=bar.update, seed=cfg.driver.samples_seed(),
                                       journal=journal, free_cycles=free)

    try:
        run = stopsignals.run(job())
    except JobStopped as exc:
        print_stopped(exc, args.json)
        return EXIT_FAULT
    except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM, SIGHUP: after the controller vented
        return print_signal_stop(stopsignals.interruption(exc), "calibration", valves[0] if valves else None,
                                 f"{len(journal.entries)} of {total} cycles are kept in {journal.path}: run again "
                                 "with --resume")
    finally:
        if operator is not None:
            operator.close()
    cal = run.calibration
    cal.save(args.out)
    if args.json:
        print(json.dumps({**cal.to_dict(), "file": str(Path(args.out)), "journal": str(journal.path),
                          "skipped": run.skipped}, indent=2))
        return EXIT_OK
    print(f"{cal.feature} against {cal.target}: {cal.fit} fit over {len(cal.x)} cycles, slope "
          f"{cal.slope:.4g} {cal.feature_unit}/{cal.target_unit}, residual sd {cal.residual_sd:.4g} "
          f"{cal.feature_unit} (r^2 {cal.r2:.4f})")
    if run.skipped:
        print(f"{len(run.skipped)} cycles gave no {cal.feature} and were left out", file=sys.stderr)
    print(f"saved {args.out} (cycles in {journal.path})")
    return EXIT_OK


def cmd_sense(args: argparse.Namespace) -> int:
    from fluidsense.controller.sensing.calibration import Calibration
    from fluidsense.daemon import app
    from fluidsense.tasks.calibrate import sense

    cal = Calibration.load(args.calibration)
    cfg = cell_config(args, default_profile=cal.profile)
    setup_logging(cfg.log_level, quiet=True)
    scene = scene_from_args(args)

    operator = Operator(cal.target, args.targets_from, args.yes) if cfg.driver.needs_operator() else None
    valves = []  # the cell's valve bank once connected: where a stop left them

    async def job():
        async with app.controller(cfg, own_process=True) as ctrl:
            valves.append(ctrl.backend.valves)
            return await sense(ctrl.task_port, cal, scene, cycles=args.cycles, place=operator.place if operator else None)

    try:
        res = stopsignals.run(job()).to_dict()
    except JobStopped as exc:
        print_stopped(exc, args.json)
        return EXIT_FAULT
    except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM, SIGHUP: after the controller vented
        return print_signal_stop(stopsignals.interruption(exc), "sensing", valves[0] if valves else None,
                                 "nothing was estimated")
    finally:
        if operator is not None:
            operator.close()
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    print(sensing_words(res, cal))
    return 0


def sensing_words(res: dict, cal) -> str:
    """The sensing result in words: a value with its interval, no object, or out of range."""
    unit, feat = res["unit"], f"{cal.feature} over {res['cycles']} cycle(s)"
    if res["status"] == "no_object":
        line = f"no object ({res['detail']}; {feat})"
    elif res["status"] == "out_of_range":
        side = "above" if res["interval"][0] is not None else "below"
        line = (f"{cal.target}: out of the calibrated range, {side} {res['bound']:g} {unit} "
                f"({res['detail']}; {feat})")
    else:
        lo, hi = res["interval"]
        line = (f"{cal.target} = {res['estimate']:.2f} {unit}  ({100 * res['coverage']:g} % interval "
                f"{lo:.2f} .. {hi:.2f}; {cal.feature} {res['measured']:.4g} {cal.feature_unit} over "
                f"{res['cycles']} cycle(s))")
    if res["truth"] is not None:
        line += f"; true {res['truth']:g}"
        if res["error"] is not None:
            line += f", error {res['error']:+.2f}"
    return line
