"""``python -m lab bench speed-accuracy``: how early can each method decide, and how well.

For the gripper on cylinders and the bending actuator over a plate, each with a fast
circuit (no resistor: only the valve's own) and a slow one (5.7e8 Pa*s/m^3, the paper's
actuation-speed study), at the default noise including cycle-to-cycle variation: every
method is calibrated on fixed targets and tested on held-out cycles whose targets are
drawn from the continuous range, at each decision time t_d. One recorded cycle gives the
features at every t_d (they only use samples up to t_d).

The actuators carry their mechanical lag (``response_s``, assumed 0.05 s): within the first
few hundred ms it moves the readings by up to 3 kPa, so these scenes need it (docs/physics.md).
Beside each method's earliest decision the bench gives the circuit's physical floor, from
noise-free step responses: when the farthest target is touched, and when the pressure has
settled to within one sample's noise.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import time
from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np

# the bench's tables and scoring (its chart uses them too); readers use them as SA.*
from .speed_spec import (  # noqa: F401
    CIRCUITS,
    DECIDED,
    DECISION_TIMES,
    FINE_STEP_OF_FLOOR,
    FINE_UP_TO_FLOORS,
    SCENES,
    _round,
    decision_times,
    earliest,
    same_as,
    times_of,
)

NAME = "speed-accuracy"
HELP = "accuracy against decision time for every sensing method (chart + summary)"
DESCRIPTION = __doc__

FIT = {"window": "linear", "early": "linear", "dp_max": "linear", "t_c_slope": "poly2", "t_c_threshold": "poly2"}
EARLY_HALF_WIDTH_MM = 2.0  # the early estimator decides once its 95 % half-width is this narrow
SEED = 1
SETTLED_KPA = 0.07  # settled: within one sample's noise sd of the final pressure


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", help="write the chart, summary and JSON into this directory")
    p.add_argument("--trials", type=int, default=200, help="held-out cycles per scene and circuit (default 200)")
    p.add_argument("--cal-cycles", type=int, default=6, help="calibration cycles per target, first dropped")
    p.add_argument("--seed", type=int, default=SEED)
    p.add_argument("--response-s", type=float, default=None, help="the actuators' mechanical lag (default "
                   "0.05 s, assumed; 0: quasi-static), to see how the figures depend on it")
    p.add_argument("--only", nargs=2, metavar=("SCENE", "CIRCUIT"), help="one scene and circuit, e.g. "
                   "gripper-cylinder fast (writes no chart)")
    p.add_argument("--jobs", "-j", type=int, default=min(2, os.cpu_count() or 1),
                   help="worker processes, one scene and circuit each (the figures do not depend on it)")
    p.add_argument("--json", action="store_true")


def _response_s(response_s: float | None) -> float:
    from ..report.common import PNEUNET_RESPONSE_S

    return PNEUNET_RESPONSE_S if response_s is None else response_s


def _profile(name: str, resistor: float, response_s: float):
    from ..report.common import profile

    prof = profile(name)
    seq = prof.sequence.model_copy(update={"charge_s": 3.0, "isolate_s": 1.0, "actuate_s": 6.0, "vent_s": 3.0,
                                           "windows": [prof.sequence.windows[0].model_copy(
                                               update={"start_s": 5.0, "end_s": 5.5})]})
    circuit = prof.circuit.model_copy(update={"resistor_pa_s_per_m3": resistor})
    actuator = prof.actuator.model_copy(update={"response_s": response_s})
    return prof.model_copy(update={"sequence": seq, "circuit": circuit, "actuator": actuator, "calibration": None})


def _scene(target: str, value: float):
    from fluidsense.common.scenes import CylinderScene, PlateScene

    return CylinderScene(diameter_mm=value) if target == "diameter_mm" else PlateScene(height_mm=value)


def floor(scene: str, circuit: str, response_s: float | None = None) -> dict[str, float]:
    """The physical floor of one scene and circuit, from noise-free step responses at both
    ends of the range: ``contact_s`` when the farthest target is touched (before it nothing
    tells the far targets apart), ``settled_s`` when every response is within SETTLED_KPA of
    its final value (after it a reading no longer depends on when it is taken)."""
    from fluidsense.simulator.timing import settled_time, step_response

    pname, target, _, (lo, hi) = SCENES[scene]
    prof = _profile(pname, CIRCUITS[circuit], _response_s(response_s))
    resps = [step_response(prof.hardware, _scene(target, x), prof.sequence.p0_kpa, 8.0) for x in (lo, hi)]
    return {"contact_s": max(r.t_contact_s for r in resps),
            "settled_s": max(settled_time(r, SETTLED_KPA) for r in resps)}


async def _collect(prof, target: str, cal_targets, test_targets, cal_cycles: int, seed: int, times):
    from fluidsense.controller.sensing.decision import features_at
    from fluidsense.controller.service import Controller
    from fluidsense.tasks.experiments import reference, sim_cell, sweep

    base = _scene(target, cal_targets[0])
    cfg, backend = sim_cell(prof, seed)
    async with Controller(cfg, backend) as ctrl:
        ref = await reference(ctrl)
        rt, rp = ref.trace
        cal = await sweep(ctrl, base, target, cal_targets, cycles=cal_cycles, drop_first=1)
        test = await sweep(ctrl, base, target, test_targets, cycles=1)
    thr = prof.sequence.contact_threshold_kpa

    def feats(runs):
        return [(r.target, features_at(*r.result.trace, rt, rp, times, contact_kpa=thr)) for r in runs]

    return feats(cal), feats(test)


def _evaluate(cal, test, method: str, td: float) -> dict[str, Any]:
    from fluidsense.controller.sensing.calibration import Calibration, CalibrationError

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


#: the suite's check (tests/system/test_speed_stability.py): this pair's rows over its first
#: CHECK_TRIALS trials are kept beside the full rows; a run of CHECK_TRIALS trials gives
#: them again exactly (each pair has its own seeded cell, and its trials come in order),
#: at a fifth of the cost of the whole pair
CHECK_PAIR, CHECK_TRIALS = ("gripper-cylinder", "fast"), 40


def _pair_rows(scene: str, circuit: str, cal, test, times) -> list[dict[str, Any]]:
    from fluidsense.controller.sensing.decision import METHODS

    rows = []
    for method in METHODS:
        for td in times:
            ev = _evaluate(cal, test, method, td)
            pairs = ev.pop("estimates")
            rows.append({"scene": scene, "circuit": circuit, "method": method, "decision_time_s": td, **ev,
                         "sorting_10mm": _sorting(pairs, 10.0), "sorting_20mm": _sorting(pairs, 20.0)})
    return rows


def _pair(args: tuple[str, str, int, int, int, float]) -> tuple[list, dict, dict | None]:
    """One scene and circuit on its own seeded cell: its rows, floor and (for CHECK_PAIR)
    check rows. The same in a worker process as in this one."""
    scene, circuit, trials, cal_cycles, seed, lag = args
    pname, target, cal_targets, (lo, hi) = SCENES[scene]
    rng = np.random.default_rng(seed)
    test_targets = [round(float(x), 3) for x in rng.uniform(lo, hi, trials)]
    prof = _profile(pname, CIRCUITS[circuit], lag)
    fl = floor(scene, circuit, lag)
    times = decision_times(fl)
    cal, test = asyncio.run(_collect(prof, target, cal_targets, test_targets, cal_cycles, seed, times))
    check = None
    if (scene, circuit) == CHECK_PAIR and trials >= CHECK_TRIALS:
        check = {"scene": scene, "circuit": circuit, "trials": CHECK_TRIALS,
                 "rows": _pair_rows(scene, circuit, cal, test[:CHECK_TRIALS], times)}
    return _pair_rows(scene, circuit, cal, test, times), fl, check


def run_bench(trials: int = 200, cal_cycles: int = 6, seed: int = SEED,
              only: tuple[str, str] | None = None, response_s: float | None = None, jobs: int = 1) -> dict[str, Any]:
    """All scenes and circuits, or ``only`` one (scene, circuit): its rows are the same
    either way (each pair has its own seeded cell), and so with ``jobs`` worker processes.
    ``check``: CHECK_PAIR's rows over its first CHECK_TRIALS trials, when the run has that many."""
    lag = _response_s(response_s)
    t0 = time.perf_counter()
    work = [(scene, circuit, trials, cal_cycles, seed, lag) for scene in SCENES for circuit in CIRCUITS
            if only is None or (scene, circuit) == tuple(only)]
    if jobs > 1 and len(work) > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
            done = list(pool.map(_pair, work))
    else:
        done = [_pair(w) for w in work]
    rows, floors, check = [], {}, None
    for (scene, circuit, *_), (pair_rows, fl, pair_check) in zip(work, done):
        rows += pair_rows
        floors[f"{scene} {circuit}"] = fl
        check = pair_check or check
    return {"rows": rows, "floors": floors, "check": check, "seed": seed, "trials": trials,
            "wall_s": time.perf_counter() - t0,
            "resistors_pa_s_per_m3": CIRCUITS, "response_s": lag, "early_half_width_mm": EARLY_HALF_WIDTH_MM,
            "settled_kpa": SETTLED_KPA}


def run(args: argparse.Namespace) -> int:
    from ._speed_chart import write

    res = run_bench(args.trials, args.cal_cycles, args.seed, tuple(args.only) if args.only else None,
                    args.response_s, jobs=max(1, args.jobs))
    if args.out and not args.only:
        write(Path(args.out), res)
    rows = _round(res["rows"])
    if args.json:
        keep = ("scene", "circuit", "method", "decision_time_s", "err95_mm", "bias_mm", "decided_fraction", "trials",
                "sorting_10mm", "sorting_20mm")
        print(json.dumps({"rows": [{k: r[k] for k in keep} for r in rows], "floors": res["floors"],
                          "response_s": res["response_s"]}, indent=1))
        return 0
    print(f"{len(rows)} rows in {res['wall_s']:.0f} s (response_s {res['response_s']:g} s)")
    for key, fl in res["floors"].items():
        print(f"{key}: farthest target touched at {fl['contact_s']:.3f} s, settled at {fl['settled_s']:.3f} s")
    if args.only:
        return 0
    for e in earliest(rows, res["trials"]):
        t = "not by 5 s" if e["decision_time_s"] is None else f"{e['decision_time_s']:g} s, {e['err95_mm']:.2f} mm"
        print(f"{e['scene']} {e['circuit']} {e['method']}: {t} (5 s window: {e['reference_err95_mm']:.2f} mm)")
    return 0
