"""``fluidsense bench speed-accuracy``: how early can each method decide, and how well.

For the gripper on cylinders and the bending actuator over a plate, each with a fast
circuit (no resistor: only the valve's own) and a slow one (5.7e8 Pa*s/m^3, the paper's
actuation-speed study), at the default noise including cycle-to-cycle variation: every
method is calibrated on fixed targets and tested on held-out cycles whose targets are
drawn from the continuous range, at each decision time t_d. One recorded cycle gives the
features at every t_d (they only use samples up to t_d).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import time
from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np

NAME = "speed-accuracy"
HELP = "accuracy against decision time for every sensing method (chart + summary)"
DESCRIPTION = __doc__

DECISION_TIMES = (0.1, 0.2, 0.3, 0.5, 1.0, 2.0, 5.0)
SCENES = {
    # scene: (profile, target field, unit, calibration targets, test range)
    "gripper-cylinder": ("pneunet-gripper", "diameter_mm", [40, 55, 70, 85, 100], (40.0, 100.0)),
    "plate-distance": ("pneunet-bending", "height_mm", [0, 10, 20, 30, 40], (0.0, 40.0)),
}
CIRCUITS = {"fast": 0.0, "slow": 5.7e8}
FIT = {"window": "linear", "early": "linear", "dp_max": "linear", "t_c_slope": "poly2", "t_c_threshold": "poly2"}
EARLY_HALF_WIDTH_MM = 2.0  # the early estimator decides once its 95 % half-width is this narrow
SEED = 1


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", help="write the chart, summary and JSON into this directory")
    p.add_argument("--trials", type=int, default=200, help="held-out cycles per scene and circuit (default 200)")
    p.add_argument("--cal-cycles", type=int, default=6, help="calibration cycles per target, first dropped")
    p.add_argument("--seed", type=int, default=SEED)
    p.add_argument("--only", nargs=2, metavar=("SCENE", "CIRCUIT"), help="one scene and circuit, e.g. "
                   "gripper-cylinder fast (writes no chart)")
    p.add_argument("--json", action="store_true")


def _profile(name: str, resistor: float):
    from ..report.common import profile

    prof = profile(name)
    seq = prof.sequence.model_copy(update={"charge_s": 3.0, "isolate_s": 1.0, "actuate_s": 6.0, "vent_s": 3.0,
                                           "windows": [prof.sequence.windows[0].model_copy(
                                               update={"start_s": 5.0, "end_s": 5.5})]})
    circuit = prof.circuit.model_copy(update={"resistor_pa_s_per_m3": resistor})
    return prof.model_copy(update={"sequence": seq, "circuit": circuit, "calibration": None})


async def _collect(prof, target: str, cal_targets, test_targets, cal_cycles: int, seed: int):
    from common.scenes import CylinderScene, PlateScene
    from controller.sensing.decision import features_at
    from controller.service import Controller
    from tasks.experiments import reference, sim_cell, sweep

    base = CylinderScene(diameter_mm=40) if target == "diameter_mm" else PlateScene(height_mm=0)
    cfg, backend = sim_cell(prof, seed)
    async with Controller(cfg, backend) as ctrl:
        ref = await reference(ctrl)
        rt, rp = ref.trace
        cal = await sweep(ctrl, base, target, cal_targets, cycles=cal_cycles, drop_first=1)
        test = await sweep(ctrl, base, target, test_targets, cycles=1)
    thr = prof.sequence.contact_threshold_kpa

    def feats(runs):
        return [(r.target, features_at(*r.result.trace, rt, rp, DECISION_TIMES, contact_kpa=thr)) for r in runs]

    return feats(cal), feats(test)


def _evaluate(cal, test, method: str, td: float) -> dict[str, Any]:
    from controller.sensing.calibration import Calibration, CalibrationError

    xs = [x for x, f in cal if f[td][method] is not None]
    ys = [f[td][method] for x, f in cal if f[td][method] is not None]
    trials = len(test)
    meta = dict(profile="", method="", feature=method, feature_unit="", scene={}, target="", target_unit="mm",
                date="bench")
    if len(set(xs)) < 3:
        return {"err95_mm": None, "bias_mm": None, "decided_fraction": 0.0, "trials": trials, "estimates": []}
    try:
        curve = Calibration.fit_points(xs, ys, FIT[method], **meta)
    except CalibrationError:
        return {"err95_mm": None, "bias_mm": None, "decided_fraction": 0.0, "trials": trials, "estimates": []}
    slope = abs(curve.slope) or 1e-12
    errs, pairs = [], []
    for x, f in test:
        v = f[td][method]
        if v is None:
            continue
        if method == "early":
            sd = f[td].get("early_sd")
            if sd is None or 1.96 * sd / slope > EARLY_HALF_WIDTH_MM:
                continue  # "not yet": the interval is still too wide
        try:
            est = curve.invert(v).estimate
        except CalibrationError:
            continue
        errs.append(est - x)
        pairs.append((x, est))
    if not errs:
        return {"err95_mm": None, "bias_mm": None, "decided_fraction": 0.0, "trials": trials, "estimates": []}
    e = np.array(errs)
    return {"err95_mm": float(np.percentile(np.abs(e), 95)), "bias_mm": float(e.mean()),
            "decided_fraction": len(errs) / trials, "trials": trials, "estimates": pairs}


def _sorting(pairs: list[tuple[float, float]], spacing: float) -> float | None:
    """Fraction of object pairs about ``spacing`` mm apart that the estimates order right."""
    ok = n = 0
    for (x1, e1), (x2, e2) in combinations(pairs, 2):
        if abs(abs(x1 - x2) - spacing) <= 1.0:
            n += 1
            ok += (x1 - x2) * (e1 - e2) > 0
    return ok / n if n else None


def run_bench(trials: int = 200, cal_cycles: int = 6, seed: int = SEED,
              only: tuple[str, str] | None = None) -> dict[str, Any]:
    """All scenes and circuits, or ``only`` one (scene, circuit): its rows are the same
    either way (each pair has its own seeded cell)."""
    from controller.sensing.decision import METHODS

    rows, t0 = [], time.perf_counter()
    for scene, (pname, target, cal_targets, (lo, hi)) in SCENES.items():
        rng = np.random.default_rng(seed)
        test_targets = [round(float(x), 3) for x in rng.uniform(lo, hi, trials)]
        for circuit, resistor in CIRCUITS.items():
            if only is not None and (scene, circuit) != tuple(only):
                continue
            prof = _profile(pname, resistor)
            cal, test = asyncio.run(_collect(prof, target, cal_targets, test_targets, cal_cycles, seed))
            for method in METHODS:
                for td in DECISION_TIMES:
                    ev = _evaluate(cal, test, method, td)
                    pairs = ev.pop("estimates")
                    rows.append({"scene": scene, "circuit": circuit, "method": method, "decision_time_s": td, **ev,
                                 "sorting_10mm": _sorting(pairs, 10.0), "sorting_20mm": _sorting(pairs, 20.0)})
    return {"rows": rows, "seed": seed, "trials": trials, "wall_s": time.perf_counter() - t0,
            "resistors_pa_s_per_m3": CIRCUITS, "early_half_width_mm": EARLY_HALF_WIDTH_MM}


def _round(rows):
    out = []
    for r in rows:
        out.append({k: (float(f"{v:.4g}") if isinstance(v, float) else v) for k, v in r.items()})
    return out


# paper points for the chart: (scene, method, t_d, err95 or bound, label)
PAPER_POINTS = [
    ("plate-distance", "window", 55.0, 1.7, "paper: tank, window 50-60 s, +-1.7 mm"),
    ("plate-distance", "t_c_slope", 60.0, 3.8, "paper: t_c, -2.9..+3.8 mm"),
    ("gripper-cylinder", "window", 5.4, 10.0, "paper: 20 mm sorting correct at 5 s (error < 10 mm)"),
    ("gripper-cylinder", "window", 0.53, 10.0, "paper: 20 mm sorting correct at 0.5 s (fast sorting)"),
]


def criterion(rows) -> dict[str, Any]:
    """The issue's question: on the gripper with the fast circuit, does some method decide
    by t_d <= 0.3 s with a 95 % error no worse than the 5 s window mean's?"""
    g = [r for r in rows if r["scene"] == "gripper-cylinder" and r["circuit"] == "fast"]
    ref = next(r for r in g if r["method"] == "window" and r["decision_time_s"] == 5.0)
    early = [r for r in g if r["decision_time_s"] <= 0.3 and r["err95_mm"] is not None
             and r["decided_fraction"] >= 0.95]
    best = min(early, key=lambda r: (r["decision_time_s"], r["err95_mm"]) if r["err95_mm"] <= ref["err95_mm"]
               else (99, r["err95_mm"]), default=None)
    met = best is not None and best["err95_mm"] <= ref["err95_mm"]
    return {"reference_err95_mm": ref["err95_mm"], "met": met,
            "best": None if best is None else {k: best[k] for k in ("method", "decision_time_s", "err95_mm",
                                                                     "decided_fraction")}}


def write(out_dir: Path, res: dict[str, Any]) -> None:
    from ..report.plots import figure, save

    out_dir.mkdir(parents=True, exist_ok=True)
    rows = res["rows"]
    (out_dir / "results.json").write_text(json.dumps({**res, "rows": _round(rows), "wall_s": None}, indent=1,
                                                     sort_keys=True) + "\n")
    from controller.sensing.decision import METHODS

    fig, ax = figure(2, 2, width=5.2, height=3.6)
    for i, scene in enumerate(SCENES):
        for j, circuit in enumerate(CIRCUITS):
            a = ax[i, j]
            for m in METHODS:
                pts = [(r["decision_time_s"], r["err95_mm"]) for r in rows
                       if r["scene"] == scene and r["circuit"] == circuit and r["method"] == m
                       and r["err95_mm"] is not None and r["decided_fraction"] >= 0.5]
                if pts:
                    a.plot(*zip(*pts), "o-", ms=3, lw=1, label=m)
            for s, m, td, err, label in PAPER_POINTS:
                if s == scene and circuit == ("slow" if scene == "plate-distance" else "fast"):
                    a.plot([td], [err], "k*", ms=9)
                    a.annotate(label, (td, err), fontsize=6, xytext=(-5, -10 if scene == "gripper-cylinder" else 6),
                               textcoords="offset points", ha="right")
            a.set_xscale("log")
            a.set_yscale("log")
            a.set_title(f"{scene}, {circuit} circuit", fontsize=9)
            a.set_xlabel("decision time after opening (s)")
            a.set_ylabel("95 % absolute error (mm)")
            a.legend(fontsize=6)
    save(fig, out_dir, "speed_accuracy.png")
    (out_dir / "README.md").write_text(_markdown(res))


def _markdown(res) -> str:
    from controller.sensing.decision import METHODS

    rows = res["rows"]
    crit = criterion(rows)
    lines = ["# Speed against accuracy", "",
             "Generated by `fluidsense bench speed-accuracy --out docs/speed-accuracy` (also `make speed-accuracy`), "
             f"seed {res['seed']}, {res['trials']} held-out cycles per scene and circuit, targets drawn uniformly "
             "from the range; calibration on fixed targets (5 of them, 5 cycles each after a dropped first) at the "
             "same decision time. Default noise: 0.07 kPa per sample plus the cycle-to-cycle variation of the "
             "regulator. Circuits: fast = no resistor (the valve's own 3e7 Pa*s/m^3), slow = 5.7e8 (the paper's "
             "actuation-speed study).", "",
             "Methods: `window` = mean over the 50 ms ending at t_d (the paper's shortest window); `early` = the "
             "first-order prediction of the equilibrium from the transient after contact (it answers \"not yet\" "
             f"until its 95 % half-width is below {res['early_half_width_mm']:g} mm); `t_c_slope` = contact time by "
             "change of slope of dP; `t_c_threshold` = dP reaching the profile's threshold; `dp_max` = largest dP so "
             "far. All use only samples up to t_d.", "", "![chart](speed_accuracy.png)", "",
             "## The question", "",
             f"On the gripper with the fast circuit, the 5 s window mean reaches a 95 % error of "
             f"{crit['reference_err95_mm']:.2f} mm. "]
    if crit["met"]:
        b = crit["best"]
        lines[-1] += (f"**`{b['method']}` decides at {b['decision_time_s']:g} s with {b['err95_mm']:.2f} mm** "
                      f"({100 * b['decided_fraction']:.0f} % of cycles decided): an order of magnitude sooner at "
                      "the same accuracy.")
    else:
        lines[-1] += "No method reaches it by 0.3 s; see the table for the physical limit."
    for scene in SCENES:
        for circuit in CIRCUITS:
            lines += ["", f"## {scene}, {circuit} circuit", "",
                      "95 % absolute error in mm (fraction of cycles decided when below 100 %):", "",
                      "| method | " + " | ".join(f"{t:g} s" for t in DECISION_TIMES) + " |",
                      "|---|" + "---|" * len(DECISION_TIMES)]
            for m in METHODS:
                cells = []
                for td in DECISION_TIMES:
                    r = next(x for x in rows if x["scene"] == scene and x["circuit"] == circuit
                             and x["method"] == m and x["decision_time_s"] == td)
                    if r["err95_mm"] is None:
                        cells.append("-")
                    else:
                        frac = "" if r["decided_fraction"] >= 0.995 else f" ({100 * r['decided_fraction']:.0f} %)"
                        cells.append(f"{r['err95_mm']:.2f}{frac}")
                lines.append(f"| {m} | " + " | ".join(cells) + " |")
            srt = [(r["decision_time_s"], r["sorting_10mm"], r["sorting_20mm"]) for r in rows
                   if r["scene"] == scene and r["circuit"] == circuit and r["method"] == "window"]
            lines += ["", "Sorting with the window mean, fraction of pairs ordered right (10 mm / 20 mm apart): "
                      + ", ".join(f"{td:g} s {'-' if a is None else f'{a:.3f}'} / {'-' if b is None else f'{b:.3f}'}"
                                  for td, a, b in srt) + "."]
    lines += ["", "## What limits each method", "",
              "- Before contact nothing about the object is in the signal: t_c and dP-based methods say nothing, "
              "and the window mean only sees the free actuator (its error is then the whole range).",
              "- After contact the window mean is biased while the transient runs, but the bias repeats cycle to "
              "cycle, so calibrating at the same t_d removes most of it; what remains is noise (0.07 kPa per sample "
              "over 50 samples) and the cycle-to-cycle variation (about 0.04 kPa on P_eq), which no decision time "
              "removes.",
              "- The early estimator needs enough post-contact samples for a tight fit; on the slow circuit contact "
              "itself comes late (hundreds of ms), so no method can decide in 0.1-0.3 s there.",
              "- t_c methods measure when the object is reached, which resolves size well for large objects (early "
              "contact) and degrades where contact comes late and the free inflation is slow.", ""]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    res = run_bench(args.trials, args.cal_cycles, args.seed, tuple(args.only) if args.only else None)
    if args.out and not args.only:
        write(Path(args.out), res)
    rows = _round(res["rows"])
    if args.json:
        keep = ("scene", "circuit", "method", "decision_time_s", "err95_mm", "bias_mm", "decided_fraction", "trials",
                "sorting_10mm", "sorting_20mm")
        print(json.dumps([{k: r[k] for k in keep} for r in rows], indent=1))
        return 0
    if args.only:
        print(f"{len(rows)} rows in {res['wall_s']:.0f} s")
        return 0
    crit = criterion(rows)
    print(f"{len(rows)} rows in {res['wall_s']:.0f} s; gripper fast circuit: 5 s window err95 "
          f"{crit['reference_err95_mm']:.2f} mm; best by 0.3 s: {crit['best']}")
    return 0
