"""``fluidsense chart``: speed against accuracy for a profile and scene, as a chart (PNG)
and its figures (JSON), from virtual-time cycles on the simulated cell."""

from __future__ import annotations

import argparse
import json
import shlex
from pathlib import Path

from fluidsense.common.errors import ConfigError
from fluidsense.common.exitcodes import EXIT_OK

from ..options import add_scene_options, floats, profile_path
from ._common import Progress, setup_logging

PNG, JSON = "speed_accuracy.png", "speed_accuracy.json"


def register(sub) -> None:
    p = sub.add_parser(
        "chart", help="chart every sensing method's accuracy against its decision time for a profile (PNG + JSON)",
        description="How early can this actuator decide, and how well? From virtual-time cycles of the profile "
        "(shipped, or your own from `fluidsense characterise`) on the simulated cell: every method calibrated on "
        "fixed targets and tested on held-out cycles at each decision time, up to the end of the profile's first "
        "window (its window mean there is the reference). Draws each method's 95 % error and decided fraction "
        "against decision time, with the floor: when the farthest target is touched and when the pressure has "
        "settled (noise-free step responses). Writes DIR/" + PNG + " and DIR/" + JSON + ".")
    p.add_argument("--profile", "-p", required=True, help="profile YAML, or a name: shipped (config/profiles/) or "
                   "NAME.yaml here (yours, e.g. from `fluidsense characterise`)")
    add_scene_options(p)
    p.add_argument("--range", help="target range lo,hi (default: the profile's calibration values)")
    p.add_argument("--targets", help="comma-separated calibration targets (default: 5 evenly over the range)")
    p.add_argument("--trials", type=int, default=200, help="held-out cycles, targets drawn uniformly from the range "
                   "(default 200; the 95 %% errors' sampling error goes as 1/sqrt of it)")
    p.add_argument("--cal-cycles", type=int, default=6, help="calibration cycles per target, the first dropped "
                   "(default 6)")
    p.add_argument("--early-half-width", type=float, metavar="W", help="the early estimator decides once its 95 %% "
                   "half-width is below W, in the target's unit (default: 1/30 of the range)")
    p.add_argument("--seed", type=int, default=1, help="seed of the simulated cell and the held-out targets "
                   "(default 1)")
    p.add_argument("--out", "-o", required=True, metavar="DIR", help="directory for the chart and its JSON")
    p.add_argument("--json", action="store_true", help="print the figures as JSON (as written to DIR)")
    p.set_defaults(func=main)


def chart_scene(args: argparse.Namespace, prof):
    """The scene the chart varies: the profile's calibration scene, or --scene KIND, with
    --set fields over it; its target field (common/scenes.TARGETS), the range (--range, or
    the profile's calibration values) and the calibration targets."""
    import numpy as np
    from fluidsense.common.models import first_error
    from fluidsense.common.scenes import TARGETS, Scene
    from fluidsense.tasks.speed_accuracy import ChartScene
    from pydantic import TypeAdapter, ValidationError

    from ..options import apply_sets

    plan = prof.calibration
    kind = args.scene or (plan.scene.kind if plan is not None else None)
    if kind is None:
        raise ConfigError(f"profile {prof.name} has no calibration section naming its scene: give --scene KIND "
                          "and --range lo,hi")
    if kind not in TARGETS:
        raise ConfigError(f"--scene {kind}: no sensing target to chart (scenes with one: {', '.join(sorted(TARGETS))})")
    target, unit = TARGETS[kind]
    own = plan is not None and plan.scene.kind == kind and plan.target == target
    if args.range:
        rng = floats(args.range, "--range")
        if len(rng) != 2:
            raise ConfigError(f"--range: expected lo,hi, got {args.range!r}")
        lo, hi = rng
    elif own:
        lo, hi = min(plan.values), max(plan.values)
    else:
        raise ConfigError(f"give --range lo,hi for {target}: the profile's calibration values are not for a "
                          f"{kind} scene")
    if not hi > lo:
        raise ConfigError(f"--range needs lo < hi, got {lo:g},{hi:g}")
    data = {**(plan.scene.model_dump() if own else {}), "kind": kind, target: lo}
    apply_sets(data, args.set)
    try:
        base = TypeAdapter(Scene).validate_python(data)
    except ValidationError as exc:
        raise ConfigError(f"--scene/--set: {first_error(exc, 'scene', skip=1)}") from None
    cal = floats(args.targets, "--targets") if args.targets else [round(float(x), 6) for x in np.linspace(lo, hi, 5)]
    if len(set(cal)) < 3:
        raise ConfigError("--targets: at least 3 distinct calibration targets (a curve and its spread)")
    return ChartScene(base=base, target=target, unit=unit, calibration=tuple(cal), range=(lo, hi))


def source_words(prof, path: Path) -> str:
    """Where the profile's numbers come from: characterised on a rig, or shipped."""
    prov = prof.provenance
    if prov is None:
        return (f"profile {path.name}: not characterised, no provenance (a shipped profile's numbers come from the "
                "paper)")
    fitted = ", ".join(f.field.split(".")[-1] for f in prov.fitted)
    return f"characterised on {prov.rig}, {prov.date[:10]} (fitted: {fitted})"


def command(args: argparse.Namespace) -> str:
    """The command line that makes this chart again (every option that changes a figure)."""
    words = ["fluidsense", "chart", "--profile", args.profile]
    if args.scene:
        words += ["--scene", args.scene]
    for item in args.set:
        words += ["--set", item]
    for flag, value in (("--range", args.range), ("--targets", args.targets),
                        ("--early-half-width", args.early_half_width)):
        if value is not None:
            words += [flag, str(value)]
    words += ["--trials", str(args.trials), "--cal-cycles", str(args.cal_cycles), "--seed", str(args.seed),
              "--out", args.out]
    return shlex.join(words)


def main(args: argparse.Namespace) -> int:
    from fluidsense.controller.config import load_profile
    from fluidsense.controller.service import open_cell
    from fluidsense.tasks import speed_accuracy as sa

    from ..speed_chart import draw, pyplot

    setup_logging("INFO", quiet=True)
    path = profile_path(args.profile)
    prof = load_profile(path)
    scene = chart_scene(args, prof)
    prepared, plan = sa.for_profile(prof, scene, trials=args.trials, cal_cycles=args.cal_cycles, seed=args.seed,
                                    early_half_width=args.early_half_width)
    pyplot()  # before the cycles: a missing matplotlib is said at once, not after minutes
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {args.out}: exists and is not a directory")
    with Progress(sa.steps(scene, plan), f"charting {prof.name}") as bar:
        res = sa.chart(prepared, scene, plan, progress=bar, open_cell=open_cell)
    source = source_words(prof, path)
    res = {"command": command(args), "profile_file": str(path.resolve()), "source": source,
           "provenance": None if prof.provenance is None else {
               "rig": prof.provenance.rig, "date": prof.provenance.date,
               "fitted": [f.field for f in prof.provenance.fitted]}, **res}
    out.mkdir(parents=True, exist_ok=True)
    text = json.dumps(res, indent=1) + "\n"
    (out / JSON).write_text(text)
    draw(res, out / PNG, source)
    if args.json:
        print(text, end="")
        return EXIT_OK
    _summary(res, out)
    return EXIT_OK


def _summary(res: dict, out: Path) -> None:
    unit, fl, ref = res["unit"], res["floor"], res["reference"]
    lo, hi = res["range"]
    print(f"{res['profile']}: {res['target']} over [{lo:g}, {hi:g}] {unit}, {res['trials']} held-out cycles "
          f"(seed {res['seed']}); {res['source']}")
    print(f"  floor: farthest target touched at {fl['contact_s']:.3g} s, settled within {fl['settled_kpa']:.2g} kPa "
          f"at {fl['settled_s']:.3g} s")
    print(f"  reference: the window mean at {ref['decision_time_s']:g} s, 95 % error {ref['err95']:.3g} {unit}")
    print(f"  earliest decision at that accuracy (at least {100 * res['decided_at']:.0f} % of cycles decided, "
          f"within {100 * res['same_as']:.1f} %):")
    for e in res["earliest"]:
        when = ("not by the reference" if e["decision_time_s"] is None
                else f"{e['decision_time_s']:g} s, {e['err95']:.3g} {unit}")
        print(f"    {e['method']:<14} {when}")
    print(f"  wrote {out / PNG} and {out / JSON} ({res['wall_s']:.0f} s)")
