"""``fluidsense design``: recommend tank volume and P0 for a profile and a target range."""

from __future__ import annotations

import argparse
import json

from common.errors import ConfigError

from ..options import profile_path


def register(sub) -> None:
    p = sub.add_parser(
        "design", help="recommend tank volume and P0 for the best resolution over a target range",
        description="Search tank volume and P0 for the largest worst-case resolution |dP_eq/dxi| over the "
        "target range, keeping contact at every target, P0 inside the profile's limits and P_eq inside the "
        "sensor's range (paper eq. 1-2 solved with the actuator's volume law; see docs/physics.md).")
    p.add_argument("--profile", "-p", required=True, help="profile YAML or name in config/profiles/")
    p.add_argument("--range", help="target range lo,hi (default: the profile's calibration values)")
    p.add_argument("--points", type=int, default=5, help="targets evaluated across the range (default 5)")
    p.add_argument("--tanks", help="comma-separated tank volumes in litres (default: 24 from 1/10 to 10x)")
    p.add_argument("--p0", help="comma-separated P0 values in kPa (default: 24 up to the profile's limit)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=main)


def _floats(text: str, name: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ConfigError(f"{name}: expected comma-separated numbers, got {text!r}") from None


def main(args: argparse.Namespace) -> int:
    import numpy as np

    from common.scenes import TARGETS
    from controller.config import load_profile
    from simulator.resolution import evaluate, search
    from tasks.calibrate import scene_with

    prof = load_profile(profile_path(args.profile))
    plan = prof.calibration
    if plan is None:
        raise ConfigError(f"profile {prof.name} has no calibration section naming its scene and target")
    if args.range:
        lo, hi = _floats(args.range, "--range")
    else:
        lo, hi = min(plan.values), max(plan.values)
    if not hi > lo or args.points < 2:
        raise ConfigError("--range needs lo < hi and --points >= 2")
    targets = list(np.linspace(lo, hi, args.points))
    circuit = prof.circuit
    if circuit.kind != "tank":
        raise ConfigError(f"design searches tank volume and P0: profile {prof.name} uses a {circuit.kind} circuit")
    vacuum = prof.sequence.p0_kpa < 0
    tanks = _floats(args.tanks, "--tanks") if args.tanks else list(np.geomspace(circuit.tank_l / 10,
                                                                                  circuit.tank_l * 10, 24))
    limit = prof.limits.min_kpa if vacuum else prof.limits.max_kpa
    p0s = _floats(args.p0, "--p0") if args.p0 else list(np.linspace(limit / 24, limit, 24))

    def scene_at(x):
        return scene_with(plan.scene, plan.target, x)

    limits = (prof.limits.min_kpa, prof.limits.max_kpa)
    sensor = tuple(prof.sensor.range_kpa)
    p_atm = circuit.p_atm
    current = evaluate(prof.actuator, scene_at, targets, circuit.tank_l, prof.sequence.p0_kpa, p_atm, limits, sensor)
    best, grid = search(prof.actuator, scene_at, targets, tanks, p0s, p_atm, limits, sensor)
    unit = TARGETS.get(plan.scene.kind, (plan.target, ""))[1]
    out = {"profile": prof.name, "target": plan.target, "unit": unit, "range": [lo, hi],
           "resolution_unit": f"kPa/{unit}", "current": current.to_dict(),
           "recommended": None if best is None else best.to_dict(),
           "improvement": None if best is None or current.min_resolution == 0
           else best.min_resolution / current.min_resolution,
           "grid": [d.to_dict() for d in grid]}
    if args.json:
        print(json.dumps(out, indent=2))
        return 0 if best is not None else 1
    print(f"{prof.name}: {plan.target} over [{lo:g}, {hi:g}] {unit}")
    c = current
    print(f"  current:     tank {c.tank_l:.3g} L at {c.p0_kpa:.3g} kPa: worst |dP/d{plan.target}| "
          f"{c.min_resolution:.4f} kPa/{unit}, mean {c.mean_resolution:.4f}"
          + ("" if c.feasible else f"  (infeasible: {c.reason})"))
    if best is None:
        print("  no feasible tank/P0 on the grid: every one misses a target or leaves the limits")
        return 1
    print(f"  recommended: tank {best.tank_l:.3g} L at {best.p0_kpa:.3g} kPa: worst {best.min_resolution:.4f} "
          f"kPa/{unit}, mean {best.mean_resolution:.4f}, P_eq {best.p_eq_range_kpa[0]:.2f}..{best.p_eq_range_kpa[1]:.2f} kPa"
          f"  ({out['improvement']:.2f}x the current worst case)" if out["improvement"] else "")
    infeasible = sum(not d.feasible for d in grid)
    print(f"  {len(grid)} candidates, {infeasible} infeasible (missed contact, limits or sensor range)")
    return 0
