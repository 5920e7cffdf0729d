"""``fluidsense calibrate`` and ``fluidsense sense``."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from pathlib import Path

from tqdm import tqdm

from controller.calibration import FEATURES, FIT_DEGREE, Calibration
from drivers.errors import ConfigError

from .. import app
from ..options import add_cell_options, add_scene_options, cell_config, scene_from_args
from ._common import setup_logging


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
    p.add_argument("--out", "-o", default="calibration.json", help="calibration file (default calibration.json)")
    p.add_argument("--json", action="store_true", help="print the calibration as JSON")
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("sense", help="measure and invert a calibration",
                       description="Run cycles on the current (or given) scene, average the feature and invert "
                       "the calibration: the estimate with a 95 % interval from the fit's residuals and noise.")
    p.add_argument("--calibration", "-k", required=True, help="calibration file from fluidsense calibrate")
    add_cell_options(p)
    add_scene_options(p)
    p.add_argument("--cycles", type=int, default=1, help="cycles to average (default 1)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_sense)


def _operator(prompt_target: str):
    async def place(scene) -> None:
        if scene.kind == "none":
            text = "Clear the actuator (nothing touching it) and press Enter: "
        else:
            text = f"Place {scene.model_dump()} ({prompt_target}) and press Enter: "
        await asyncio.get_running_loop().run_in_executor(None, input, text)

    return place


def cmd_calibrate(args: argparse.Namespace) -> int:
    from tasks.calibrate import calibrate

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

    async def job():
        async with app.controller(cfg) as ctrl:
            place = None if ctrl.backend.scene is not None else _operator(target)
            total = len(values) * cycles
            with tqdm(total=total, desc=f"calibrating {cfg.profile.name}", unit="cycle", file=sys.stderr,
                      disable=args.json) as bar:
                return await calibrate(ctrl, scene, target, values, feature=feature, fit=fit, cycles=cycles,
                                       drop_first=drop, place=place, progress=bar.update,
                                       seed=args.seed if cfg.driver.kind == "sim" else None)

    run = asyncio.run(job())
    cal = run.calibration
    cal.save(args.out)
    if args.json:
        print(json.dumps({**cal.to_dict(), "file": str(Path(args.out)), "skipped": run.skipped}, indent=2))
        return 0
    print(f"{cal.feature} against {cal.target}: {cal.fit} fit over {len(cal.x)} cycles, slope "
          f"{cal.slope:.4g} {cal.feature_unit}/{cal.target_unit}, residual sd {cal.residual_sd:.4g} "
          f"{cal.feature_unit} (r^2 {cal.r2:.4f})")
    if run.skipped:
        print(f"{len(run.skipped)} cycles gave no {cal.feature} and were left out", file=sys.stderr)
    print(f"saved {args.out}")
    return 0


def cmd_sense(args: argparse.Namespace) -> int:
    from tasks.calibrate import sense

    cal = Calibration.load(args.calibration)
    cfg = cell_config(args, default_profile=cal.profile)
    setup_logging(cfg.log_level, quiet=True)
    scene = scene_from_args(args)

    async def job():
        async with app.controller(cfg) as ctrl:
            place = None if ctrl.backend.scene is not None else _operator(cal.target)
            return await sense(ctrl, cal, scene, cycles=args.cycles, place=place)

    res = asyncio.run(job()).to_dict()
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    lo, hi = res["interval95"]
    line = (f"{cal.target} = {res['estimate']:.2f} {res['unit']}  (95 % interval {lo:.2f} .. {hi:.2f}; "
            f"{cal.feature} {res['measured']:.4g} {cal.feature_unit} over {res['cycles']} cycle(s))")
    if res["truth"] is not None:
        line += f"; true {res['truth']:g}, error {res['error']:+.2f}"
    if res["extrapolated"]:
        line += "  [outside the calibrated range]"
    print(line)
    return 0
