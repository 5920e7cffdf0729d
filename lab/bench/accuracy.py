"""``python -m lab bench accuracy``: how far the estimates are from the truth, and whether
their intervals cover it, on cases calibration never saw.

Per case (the plate under the bending actuator: height; the gripper on cylinders:
diameter) one session calibrates with the profile's own protocol (its targets, cycles,
dropped cycles, plus the free cycles that tell "no object"). Then fresh sessions, each a
new simulated cell with another seed, sense targets drawn from the continuous calibrated
range, one cycle each, the first cycle of every session included, exactly as
``fluidsense sense`` does. The truth is the scene's geometry (the height or diameter
placed), never a measured pressure. Each session also senses the empty actuator (should
say "no object") and one object beyond the calibrated range (should say "out of range").
"""

from __future__ import annotations

import argparse
import asyncio
import json
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

NAME = "accuracy"
HELP = "95 % |error|, bias and interval coverage on held-out targets and seeds, per profile"
DESCRIPTION = __doc__

# case -> (profile, beyond-the-range target, paper's 95 % accuracy in words)
CASES: dict[str, tuple[str, float, str]] = {
    "plate": ("pneunet-bending", 50.0, "+-1.7 mm (tank method); time of first contact -2.9 to +3.8 mm"),
    "gripper": ("pneunet-gripper", 115.0, "not given as an interval (linear fit over D = 40-100 mm)"),
    "plate-pressure-flow": ("pneunet-bending-pressure-flow", 50.0, "+-4.7 mm (pressure control + flow measurement)"),
    "plate-flow-control": ("pneunet-bending-flow-control", 50.0, "+-3.4 mm (flow control + pressure measurement)"),
    "plate-tc": ("pneunet-bending", 50.0, "-2.9 to +3.8 mm (time of first contact)"),
}
# a case that reads another feature than its profile's calibration plan: (feature, fit), as
# the report's time-of-first-contact section fits it
FEATURE = {"plate-tc": ("t_c_slope", "poly2")}
CAL_SEED = 9001  # the calibration's cell; held-out sessions use other seeds
FIRST_SEED = 100


@dataclass
class Study:
    case: str
    profile: str
    target: str
    unit: str
    cal_seed: int
    seeds: list[int]
    truth: list[float] = field(default_factory=list)
    value: list[float | None] = field(default_factory=list)
    lo: list[float | None] = field(default_factory=list)
    hi: list[float | None] = field(default_factory=list)
    status: list[str] = field(default_factory=list)
    empty_status: list[str] = field(default_factory=list)
    beyond: float = 0.0
    beyond_status: list[str] = field(default_factory=list)
    beyond_bound: list[float | None] = field(default_factory=list)
    residual_sd: float = 0.0
    slope: float = 0.0

    def errors(self) -> np.ndarray:
        return np.array([v - t for v, t, s in zip(self.value, self.truth, self.status) if s == "ok"])

    def summary(self) -> dict[str, Any]:
        err = self.errors()
        ok = [s == "ok" for s in self.status]
        covered = [lo <= t <= hi for t, lo, hi, good in zip(self.truth, self.lo, self.hi, ok) if good]
        widths = [hi - lo for lo, hi, good in zip(self.lo, self.hi, ok) if good]
        return {
            "case": self.case, "profile": self.profile, "target": self.target, "unit": self.unit,
            "trials": len(self.truth), "sessions": len(self.seeds), "answered": int(sum(ok)),
            "abs_error_95": float(np.percentile(np.abs(err), 95)) if len(err) else None,
            "mean_error": float(np.mean(err)) if len(err) else None,
            "rms_error": float(np.sqrt(np.mean(err**2))) if len(err) else None,
            "coverage95": float(np.mean(covered)) if covered else None,
            "mean_interval_width": float(np.mean(widths)) if widths else None,
            "empty_no_object": f"{self.empty_status.count('no_object')}/{len(self.empty_status)}",
            "beyond": self.beyond, "beyond_out_of_range": f"{self.beyond_status.count('out_of_range')}/"
            f"{len(self.beyond_status)}",
            "calibration_residual_sd": self.residual_sd, "calibration_slope": self.slope,
            "cal_seed": self.cal_seed, "seeds": [self.seeds[0], self.seeds[-1]] if self.seeds else [],
            "paper": CASES[self.case][2],
        }


def _cell(profile_name: str, seed: int):
    from fluidsense.cli.options import profile_path
    from fluidsense.controller.config import CellConfig, load_profile
    from fluidsense.drivers.registry import SimDriverConfig

    prof = load_profile(profile_path(profile_name))
    return CellConfig(driver=SimDriverConfig(clock="virtual", seed=seed), profile=prof)


async def _calibrate(profile_name: str, seed: int, feature: tuple[str, str] | None = None):
    from fluidsense.daemon import app
    from fluidsense.tasks.calibrate import calibrate

    cfg = _cell(profile_name, seed)
    plan = cfg.profile.calibration
    name, fit = feature or (plan.feature, plan.fit)
    async with app.controller(cfg) as ctrl:
        run = await calibrate(ctrl.task_port, plan.scene, plan.target, plan.values, feature=name, fit=fit,
                              cycles=plan.cycles, drop_first=plan.drop_first, seed=seed, free_cycles=plan.cycles)
    return run.calibration


async def _session(cal, profile_name: str, seed: int, targets: list[float], beyond: float, study: Study) -> None:
    """One fresh cell: the held-out targets (its first cycle is the session's first), the
    empty actuator, one object beyond the range."""
    from fluidsense.common.names import FEATURES
    from fluidsense.common.scenes import EmptyScene
    from fluidsense.controller.sensing.calibration import feature_value
    from fluidsense.daemon import app
    from fluidsense.tasks.calibrate import NEEDS_REFERENCE, ensure_reference, scene_with

    cfg = _cell(profile_name, seed)
    plan = cfg.profile.calibration
    scale = FEATURES[cal.feature][2]
    _, factor = _si(cal.target_unit)

    async def measure(scene):
        await ctrl.scene.place(scene)
        res = await ctrl.run_cycle(label="held-out")
        if not res.ok:
            raise RuntimeError(f"cycle {res.cycle_id} ended: {res.aborted}")
        y = feature_value(res, cal.feature)
        return cal.estimate(None if y is None else y / scale)

    async with app.controller(cfg) as ctrl:
        if cal.feature in NEEDS_REFERENCE:  # a fresh session records its own free-air reference first
            await ensure_reference(ctrl.task_port, ctrl.scene.place)
        for x in targets:
            est = await measure(scene_with(plan.scene, plan.target, x))
            study.truth.append(x)
            study.status.append(est.status)
            study.value.append(None if est.value is None else est.value / factor)
            study.lo.append(None if est.lo is None else est.lo / factor)
            study.hi.append(None if est.hi is None else est.hi / factor)
        study.empty_status.append((await measure(EmptyScene())).status)
        est = await measure(scene_with(plan.scene, plan.target, beyond))
        study.beyond_status.append(est.status)
        study.beyond_bound.append(None if est.bound is None else est.bound / factor)


def _si(unit: str):
    from fluidsense.controller.sensing.estimate import si_unit

    return si_unit(unit)


def study(case: str, sessions: int, per_session: int, cal_seed: int = CAL_SEED, first_seed: int = FIRST_SEED,
          calibration=None) -> Study:
    """Calibrate once (or use ``calibration``), then ``sessions`` fresh cells with
    ``per_session`` held-out targets each."""
    profile_name, beyond, _ = CASES[case]
    cal = calibration if calibration is not None else asyncio.run(_calibrate(profile_name, cal_seed,
                                                                           FEATURE.get(case)))
    lo, hi = min(cal.x), max(cal.x)
    seeds = list(range(first_seed, first_seed + sessions))
    st = Study(case, profile_name, cal.target, cal.target_unit, cal_seed, seeds, beyond=beyond,
               residual_sd=cal.residual_sd, slope=cal.slope)
    for seed in seeds:
        rng = np.random.default_rng([seed, 16])
        targets = [float(round(v, 2)) for v in rng.uniform(lo, hi, per_session)]
        asyncio.run(_session(cal, profile_name, seed, targets, beyond, st))
    return st


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("--case", choices=list(CASES), action="append", help="one case (repeatable; default all)")
    p.add_argument("--sessions", type=int, default=20, help="fresh cells (seeds) per case (default 20)")
    p.add_argument("--per-session", type=int, default=5, help="held-out targets per session (default 5)")
    p.add_argument("--cal-seed", type=int, default=CAL_SEED, help=f"the calibration's cell (default {CAL_SEED})")
    p.add_argument("--first-seed", type=int, default=FIRST_SEED,
                   help=f"held-out sessions use seeds from this one up (default {FIRST_SEED})")
    p.add_argument("--json", action="store_true")


def run(args: argparse.Namespace) -> int:
    out = []
    for case in args.case or list(CASES):
        t0 = time.monotonic()
        s = study(case, args.sessions, args.per_session, cal_seed=args.cal_seed, first_seed=args.first_seed).summary()
        s["wall_s"] = round(time.monotonic() - t0, 1)
        out.append(s)
        if not args.json:
            print(_words(s), flush=True)
    if args.json:
        print(json.dumps(out, indent=2))
    return 0


def _words(s: dict[str, Any]) -> str:
    u = s["unit"]
    return (f"{s['case']} ({s['profile']}, {s['target']}): {s['trials']} held-out targets over {s['sessions']} "
            f"fresh sessions, {s['answered']} answered\n"
            f"  95 % |error| {s['abs_error_95']:.2f} {u}, mean error {s['mean_error']:+.2f} {u}, rms "
            f"{s['rms_error']:.2f} {u}; 95 % intervals cover the truth in {100 * s['coverage95']:.1f} % "
            f"(mean width {s['mean_interval_width']:.2f} {u})\n"
            f"  empty actuator -> no object in {s['empty_no_object']}; {s['beyond']:g} {u} -> out of range in "
            f"{s['beyond_out_of_range']}\n  paper: {s['paper']}  [{s['wall_s']} s]")
