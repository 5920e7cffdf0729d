"""``fluidsense design``: recommend tank volume and P0 for a profile and a target range."""

from __future__ import annotations

import argparse
import json

from fluidsense.common.errors import ConfigError

from ..options import floats, profile_path


def register(sub) -> None:
    p = sub.add_parser(
        "design", help="recommend tank volume and P0 for the best resolution over a target range",
        description="Search tank volume and P0 for the largest worst-case resolution |dP_eq/dxi| over the "
        "target range, keeping contact at every target, P0 inside the profile's limits and P_eq inside the "
        "sensor's range (paper eq. 1-2 solved with the actuator's volume law; see docs/physics.md).")
    p.add_argument("--profile", "-p", required=True, help="profile YAML, or a name: shipped (config/profiles/) or "
                   "NAME.yaml here (yours, e.g. from `fluidsense characterise`)")
    p.add_argument("--range", help="target range lo,hi (default: the profile's calibration values)")
    p.add_argument("--points", type=int, default=5, help="targets evaluated across the range (default 5)")
    p.add_argument("--tanks", help="comma-separated tank volumes in litres (default: 24 from 1/10 to 10x)")
    p.add_argument("--p0", help="comma-separated P0 values in kPa (default: 24 up to the profile's limit)")
    p.add_argument("--resolution-mm", type=float, metavar="R", help="the accuracy needed: 95 %% half-width of one "
                   "reading, in the target's unit (mm, deg...); with --decide-by-s: design for it")
    p.add_argument("--decide-by-s", type=float, metavar="T", help="seconds after the valve opens by which the "
                   "reading must be done")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=main)


def provenance(prof) -> dict | None:
    """Where a characterised profile's numbers came from (None: a shipped profile's, from
    the paper): the rig, the date and the fitted fields with their 95 % intervals."""
    prov = prof.provenance
    if prov is None:
        return None
    return {"rig": prov.rig, "date": prov.date, "from_profile": prov.from_profile,
            "fitted": {f.field: {"value": f.value, "lo95": f.lo95, "hi95": f.hi95, "unit": f.unit}
                       for f in prov.fitted}}


def provenance_line(prof) -> str:
    prov = prof.provenance
    if prov is None:
        return "  numbers: the profile's own (not characterised: no provenance)"
    law = [f for f in prov.fitted if f.field.startswith("actuator.")]
    return (f"  numbers: characterised on {prov.rig}, {prov.date[:10]}"
            + "".join(f"; {f.field.split('.')[-1]} {f.value:.4g} [{f.lo95:.4g}, {f.hi95:.4g}] {f.unit}" for f in law))


def main(args: argparse.Namespace) -> int:
    import numpy as np
    from fluidsense.common.scenes import TARGETS
    from fluidsense.controller.config import load_profile
    from fluidsense.simulator.resolution import evaluate, search
    from fluidsense.tasks.calibrate import scene_with

    prof = load_profile(profile_path(args.profile))
    plan = prof.calibration
    if plan is None:
        raise ConfigError(f"profile {prof.name} has no calibration section naming its scene and target")
    if args.range:
        lo, hi = floats(args.range, "--range")
    else:
        lo, hi = min(plan.values), max(plan.values)
    if not hi > lo or args.points < 2:
        raise ConfigError("--range needs lo < hi and --points >= 2")
    targets = list(np.linspace(lo, hi, args.points))
    circuit = prof.circuit
    if circuit.kind != "tank":
        raise ConfigError(f"design searches tank volume and P0: profile {prof.name} uses a {circuit.kind} circuit")
    vacuum = prof.sequence.p0_kpa < 0
    tanks = floats(args.tanks, "--tanks") if args.tanks else list(np.geomspace(circuit.tank_l / 10,
                                                                                  circuit.tank_l * 10, 24))
    limit = prof.limits.min_kpa if vacuum else prof.limits.max_kpa
    p0s = floats(args.p0, "--p0") if args.p0 else list(np.linspace(limit / 24, limit, 24))

    def scene_at(x):
        return scene_with(plan.scene, plan.target, x)

    if (args.resolution_mm is None) != (args.decide_by_s is None):
        raise ConfigError("give --resolution-mm and --decide-by-s together")
    if args.resolution_mm is not None:
        if not args.resolution_mm > 0 or not args.decide_by_s > 0:
            raise ConfigError("--resolution-mm and --decide-by-s must be positive")
        margin = prof.p0_margin_kpa
        if not args.p0:
            top = limit - margin if not vacuum else limit + margin
            p0s = list(np.linspace(top / 24, top, 24))
        return _requirement(args, prof, plan, scene_at, targets, tanks, p0s, lo, hi)

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
           "grid": [d.to_dict() for d in grid], "provenance": provenance(prof)}
    if args.json:
        print(json.dumps(out, indent=2))
        return 0 if best is not None else 1
    print(f"{prof.name}: {plan.target} over [{lo:g}, {hi:g}] {unit}")
    print(provenance_line(prof))
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


def _requirement(args, prof, plan, scene_at, targets, tanks, p0s, lo, hi) -> int:
    """Design for an accuracy by a decision time (simulator/design.py)."""
    from fluidsense.common.scenes import TARGETS
    from fluidsense.simulator.design import recommend

    unit = TARGETS.get(plan.scene.kind, (plan.target, ""))[1]
    best, grid, why = recommend(prof, scene_at, targets, tanks, p0s, args.resolution_mm, args.decide_by_s)
    out = {"profile": prof.name, "target": plan.target, "unit": unit, "range": [lo, hi],
           "resolution": args.resolution_mm, "decide_by_s": args.decide_by_s,
           "noise_sd_kpa": prof.sensor.noise_sd_kpa, "p0_margin_kpa": prof.p0_margin_kpa,
           "recommended": None if best is None else best.to_dict(), "why_none": why or None,
           "candidates": len(grid), "meeting": sum(g.meets for g in grid), "provenance": provenance(prof)}
    if args.json:
        print(json.dumps(out, indent=2))
        return 0 if best is not None else 1
    print(f"{prof.name}: {plan.target} over [{lo:g}, {hi:g}] {unit}, +-{args.resolution_mm:g} {unit} (95 %) by "
          f"{args.decide_by_s:g} s after opening, sensor noise {prof.sensor.noise_sd_kpa:g} kPa")
    print(provenance_line(prof))
    if best is None:
        print(f"  no design reaches it: {why}")
        return 1
    print(f"  recommended: tank {best.tank_l:.3g} L at P0 {best.p0_kpa:.3g} kPa (limit {prof.limits.max_kpa:g} kPa, "
          f"margin {prof.p0_margin_kpa:.2f}): predicted +-{best.half_width:.2f} {unit} per reading, "
          f"settled after {best.settle_s:.2f} s, window {best.window_s:.2f} s before {args.decide_by_s:g} s; "
          f"worst |dP/d{plan.target}| {best.resolution_kpa:.4f} kPa/{unit}")
    print(f"  {out['meeting']} of {len(grid)} candidates meet it; the lowest P0 is recommended")
    return 0
