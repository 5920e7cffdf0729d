"""``python -m lab bench grips``: does an empty gripper read empty, and an object an object,
through the production drivers on a busy robot PC?

For each driver (``ur``: config/cell-ur-sim.yaml, ``modbus``: config/cell-modbus-sim.yaml,
both the sorting gripper as shipped, only their addresses and sockets moved) and each load
(``--loads``, busy processes beside the cell), it starts ``fluidsense simcell`` and
``fluidsense run`` as an integrator would, takes one free-air reference, then grips
nothing ``--empty`` times and each cylinder of ``--sizes`` ``--objects`` times (typed
client: grip, read the grasp, release), in a shuffled order so that a drift in the cell or
the load does not fall on one kind of grip. It prints the false-object rate (an empty grip
that read an object), the missed-object rate (an object that did not), the uncertain
answers (object null, with their reason), the grips a fault ended (vented; the daemon is
reset and the next grip goes on), the features of every grip that was not right, and
the alignment's error: the rise shift the daemon found against the valve's true timing
(when the box's valve log says it opened, against when the daemon commanded it, each taken
from the reference's). Figures in docs/performance.md ("Empty grips and objects"); ``make
grips`` writes docs/performance/grips.json.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

NAME = "grips"
HELP = "empty grips and grips on cylinders through ur and modbus, quiet and beside busy processes"
DESCRIPTION = __doc__
FEATURES = ("p_eq_kpa", "dp_eq_kpa", "dp_max_kpa", "t_c_threshold_s", "object_bound_kpa")


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("--drivers", default="ur,modbus", help="comma-separated (default ur,modbus)")
    p.add_argument("--loads", default="0,2", help="busy processes beside the cell, one run each (default 0,2)")
    p.add_argument("--empty", type=int, default=20, help="empty grips per driver and load (default 20)")
    p.add_argument("--sizes", default="40,60,100", help="cylinder diameters, mm (default 40,60,100)")
    p.add_argument("--objects", type=int, default=5, help="grips per cylinder, driver and load (default 5)")
    p.add_argument("--reference-lag-ms", type=float, default=0.0,
                   help="valve commands reach the valves this late while the reference is taken (the box's "
                        "command_lag: a PC busy at that moment), default 0")
    p.add_argument("--seed", type=int, default=1, help="seed of the grips' order")
    p.add_argument("--json", action="store_true")


def _grips(kind: str, load: int, plan: list[float | None], reference_lag_s: float = 0.0) -> dict[str, Any]:
    """One box and daemon; a free-air reference, then the grips of ``plan`` (None: empty)."""
    from fluidsense.client import Gripper
    from fluidsense.client.types import GripEnded, Refused
    from fluidsense.simulator.controlbox.process import EmulatorProcess, free_loopback

    from lab import REPO

    from .tasks import _cell
    from .timing import _burn

    out: dict[str, Any] = {"driver": kind, "load": load, "grips": [], "idle_faults": []}
    burners = [multiprocessing.Process(target=_burn, args=(time.monotonic() + 1e6,), daemon=True)
               for _ in range(load)]
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="fluidsense-bench-grips-") as d:
        cell = _cell(Path(d), kind, free_loopback(), references={"keep": False})
        box = EmulatorProcess(command=[sys.executable, "-m", "fluidsense", "simcell", "--config", str(cell)])
        box.start(timeout_s=60)
        daemon = subprocess.Popen([sys.executable, "-m", "fluidsense", "run", "--config", str(cell)],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=REPO)
        try:
            for b in burners:
                b.start()
            with Gripper(f"ipc://{d}/cmd-{kind}", f"ipc://{d}/pub-{kind}", timeout_s=120,
                         topics=("grasp", "released", "fault", "cycle")) as g:
                while g.status()["state"] == "connecting":
                    time.sleep(0.5)  # a bench waiting for the daemon's connection, nothing measured
                g.scene({"kind": "none"})
                box.command({"cmd": "command_lag", "lag_s": reference_lag_s})
                ref = g.measure(store_reference=True, wait=False)
                g.wait_for("grasp", ref, 120.0)
                ref_open = _opened(box)
                g.wait_for("released", ref, 120.0)
                ref_timing = ref_open - g.wait_for("cycle", ref, 120.0).data["t_open_s"]
                box.command({"cmd": "command_lag", "lag_s": 0.0})
                for size in plan:
                    g.scene({"kind": "none"} if size is None else {"kind": "cylinder", "diameter_mm": size})
                    fault = g.status().get("fault")
                    if fault:  # latched while idle (a no_data between grips): counted, reset, on
                        out["idle_faults"].append(f"{fault['kind']}: {fault['detail']}")
                        g.reset()
                    try:
                        grasp = g.grip()
                    except (GripEnded, Refused) as exc:  # a fault ended or refused it (vented): counted, reset, on
                        out["grips"].append({"size_mm": size, "object": None, "contact": None, "faulted": str(exc),
                                             "note": None, **dict.fromkeys(FEATURES), "rise_shift_s": None,
                                         "true_shift_s": None})
                        g.reset()
                        continue
                    opened = _opened(box)
                    g.release()
                    timing = opened - g.wait_for("cycle", grasp.cycle_id, 120.0).data["t_open_s"]
                    out["grips"].append({"faulted": None, "size_mm": size, "object": grasp.object, "contact": grasp.contact,
                                         "note": grasp.note, **{k: grasp.features.get(k) for k in FEATURES},
                                         "rise_shift_s": grasp.features.get("rise_shift_s"),
                                         "true_shift_s": timing - ref_timing})
        finally:
            for b in burners:
                if b.is_alive():
                    b.terminate()
                b.join()
            daemon.terminate()
            daemon.wait(60)
            box.stop()
            box.__exit__(None, None, None)
    out["wall_s"] = round(time.monotonic() - t0, 1)
    return out


def _opened(box: Any) -> float:
    """When the actuation valve last really opened, box time (the box's valve log). Taken
    against the cycle's commanded time (sample time) and the reference's, both clocks'
    origins drop out: both run on the monotonic clock."""
    log = box.command({"cmd": "valve_log"})["valves"]
    return [v["effective_s"] for v in log if v["valve"] == "actuate" and v["open"]][-1]


def _median(values: list[float | None]) -> float | None:
    import numpy as np

    vals = [v for v in values if v is not None]
    return round(float(np.median(vals)), 4) if vals else None


def _percentiles(values: list[float | None]) -> dict[str, float] | None:
    """5th, 50th and 95th percentile, and the largest magnitude, in ms."""
    import numpy as np

    vals = np.array([v for v in values if v is not None]) * 1e3
    if not len(vals):
        return None
    p5, p50, p95 = np.percentile(vals, [5, 50, 95])
    return {"p5": round(float(p5), 2), "p50": round(float(p50), 2), "p95": round(float(p95), 2),
            "max_abs": round(float(np.abs(vals).max()), 2), "n": int(len(vals))}


def summarise(run: dict[str, Any]) -> dict[str, Any]:
    """Rates of one run, and the grips that were not right."""
    empty = [g for g in run["grips"] if g["size_mm"] is None]
    full = [g for g in run["grips"] if g["size_mm"] is not None]
    wrong = [g for g in empty if g["object"] is not False and not g["faulted"]] + \
        [g for g in full if g["object"] is not True and not g["faulted"]]
    faulted = [g for g in run["grips"] if g["faulted"]]
    return {"driver": run["driver"], "load": run["load"], "wall_s": run["wall_s"],
            "empty": len(empty), "false_object": sum(g["object"] is True for g in empty),
            "empty_uncertain": sum(g["object"] is None and not g["faulted"] for g in empty),
            "objects": len(full), "missed_object": sum(g["object"] is False for g in full),
            "object_uncertain": sum(g["object"] is None and not g["faulted"] for g in full),
            "faulted": len(faulted), "faults": sorted({g["faulted"] for g in faulted}),
            "idle_faults": run["idle_faults"],
            "per_size": {f"{s:g}": sum(g["object"] is True for g in full if g["size_mm"] == s)
                         for s in sorted({g["size_mm"] for g in full})},
            "dp_eq_kpa_median": {("empty" if s is None else f"{s:g}"): _median(
                [g["dp_eq_kpa"] for g in run["grips"] if g["size_mm"] == s]) for s in
                [None, *sorted({g["size_mm"] for g in full})]},
            "object_bound_kpa": _median([g["object_bound_kpa"] for g in run["grips"]]),
            "aligned": sum(g["rise_shift_s"] is not None for g in run["grips"]), "grips": len(run["grips"]),
            "true_shift_ms": _percentiles([g["true_shift_s"] for g in run["grips"]]),
            "alignment_error_ms": _percentiles([g["rise_shift_s"] - g["true_shift_s"] for g in run["grips"]
                                                if g["rise_shift_s"] is not None and g["true_shift_s"] is not None]),
            "wrong": wrong}


def run_bench(drivers: list[str], loads: list[int], empty: int, sizes: list[float], objects: int,
              seed: int, reference_lag_s: float = 0.0) -> dict[str, Any]:
    import numpy as np

    rng = np.random.default_rng(seed)
    runs = []
    for kind in drivers:
        for load in loads:
            plan: list[float | None] = [None] * empty + [s for s in sizes for _ in range(objects)]
            plan = [plan[i] for i in rng.permutation(len(plan))]
            runs.append(summarise(_grips(kind, load, plan, reference_lag_s)))
    return {"cpus": os.cpu_count(), "reference_lag_s": reference_lag_s, "empty_per_run": empty, "sizes_mm": sizes, "objects_per_size": objects,
            "runs": runs}


def run(args: argparse.Namespace) -> int:
    res = run_bench([d for d in args.drivers.split(",") if d], [int(x) for x in args.loads.split(",") if x],
                    args.empty, [float(x) for x in args.sizes.split(",") if x], args.objects, args.seed,
                    args.reference_lag_ms / 1e3)
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    print(f"{res['cpus']} CPUs; per run {res['empty_per_run']} empty grips and {res['objects_per_size']} on each of "
          f"{', '.join(f'{s:g}' for s in res['sizes_mm'])} mm; the reference taken "
          f"{res['reference_lag_s'] * 1e3:g} ms late")
    for r in res["runs"]:
        print(f"{r['driver']:6s} load {r['load']}: empty read as an object {r['false_object']}/{r['empty']} "
              f"(uncertain {r['empty_uncertain']}); object missed {r['missed_object']}/{r['objects']} "
              f"(uncertain {r['object_uncertain']}); read as an object per size {r['per_size']}; "
              f"ended by a fault {r['faulted']}; {r['wall_s']:.0f} s")
        for f in r["faults"]:
            print(f"    fault: {f}")
        for f in r["idle_faults"]:
            print(f"    fault while idle between grips (reset): {f}")
        print(f"    median dP_eq (kPa) {r['dp_eq_kpa_median']} against the bound {r['object_bound_kpa']}; "
              f"aligned on the rise {r['aligned']}/{r['grips']}")
        print(f"    valve timing against the reference's (ms) {r['true_shift_ms']}; "
              f"alignment's error (found - true, ms) {r['alignment_error_ms']}")
        for g in r["wrong"]:
            size = "empty" if g["size_mm"] is None else f"{g['size_mm']:g} mm"
            print(f"    {size}: object {g['object']}, " + ", ".join(f"{k} {g[k]}" for k in FEATURES)
                  + f", rise_shift_s {g['rise_shift_s']}, true_shift_s {g['true_shift_s']}; {g['note']}")
    return 0
