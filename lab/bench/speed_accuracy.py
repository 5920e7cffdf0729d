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

The cycles, the floor and the scoring are the product's (tasks/speed_accuracy.py, which
``fluidsense chart`` runs for any profile and scene); this study gives it the paper's two
scenes, their circuits and lag, and writes docs/speed-accuracy (_speed_chart.py).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

from fluidsense.tasks import speed_accuracy as core

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

EARLY_HALF_WIDTH_MM = 2.0  # the early estimator decides once its 95 % half-width is this narrow
SEED = 1
SETTLED_KPA = core.SETTLED_KPA  # settled: within one sample's noise sd (0.07 kPa) of the final pressure


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


def chart_scene(scene: str) -> core.ChartScene:
    """One of the paper's scenes as the product's chart takes it."""
    _, target, cal_targets, (lo, hi) = SCENES[scene]
    return core.ChartScene(base=_scene(target, cal_targets[0]), target=target, unit="mm",
                           calibration=tuple(cal_targets), range=(lo, hi))


def plan(trials: int = 200, cal_cycles: int = 6, seed: int = SEED) -> core.Plan:
    """The paper's scenes' grid (DECISION_TIMES, up to the 5 s reference), floor band and
    early gate, and the sorting scored at 10 and 20 mm."""
    return core.Plan(trials=trials, cal_cycles=cal_cycles, seed=seed, early_half_width=EARLY_HALF_WIDTH_MM,
                     settled_kpa=SETTLED_KPA, sorting=(10.0, 20.0))


def floor(scene: str, circuit: str, response_s: float | None = None) -> dict[str, float]:
    """The physical floor of one scene and circuit (tasks/speed_accuracy.floor): when the
    farthest target is touched, and when every response is within SETTLED_KPA of its final
    value."""
    pname = SCENES[scene][0]
    return core.floor(_profile(pname, CIRCUITS[circuit], _response_s(response_s)), chart_scene(scene), SETTLED_KPA)


#: the suite's check (tests/system/test_speed_stability.py): this pair's rows over its first
#: CHECK_TRIALS trials are kept beside the full rows; a run of CHECK_TRIALS trials gives
#: them again exactly (each pair has its own seeded cell, and its trials come in order),
#: at a fifth of the cost of the whole pair
CHECK_PAIR, CHECK_TRIALS = ("gripper-cylinder", "fast"), 40


def _pair_rows(scene: str, circuit: str, rows) -> list[dict[str, Any]]:
    """The product's rows (tasks/speed_accuracy.score) in this study's terms: scene, circuit,
    errors in mm, the sorting at 10 and 20 mm."""
    return [{"scene": scene, "circuit": circuit, "method": r["method"], "decision_time_s": r["decision_time_s"],
             "err95_mm": r["err95"], "bias_mm": r["bias"], "decided_fraction": r["decided_fraction"],
             "trials": r["trials"], "sorting_10mm": r["sorting"][10.0], "sorting_20mm": r["sorting"][20.0]}
            for r in rows]


def _pair(args: tuple[str, str, int, int, int, float]) -> tuple[list, dict, dict | None]:
    """One scene and circuit on its own seeded cell: its rows, floor and (for CHECK_PAIR)
    check rows. The same in a worker process as in this one."""
    from fluidsense.controller.service import open_cell

    scene, circuit, trials, cal_cycles, seed, lag = args
    how = plan(trials, cal_cycles, seed)
    measured = core.measure(_profile(SCENES[scene][0], CIRCUITS[circuit], lag), chart_scene(scene), how,
                            open_cell=open_cell)
    check = None
    if (scene, circuit) == CHECK_PAIR and trials >= CHECK_TRIALS:
        check = {"scene": scene, "circuit": circuit, "trials": CHECK_TRIALS,
                 "rows": _pair_rows(scene, circuit, core.score(measured, how, trials=CHECK_TRIALS))}
    return _pair_rows(scene, circuit, core.score(measured, how)), measured.floor, check


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
