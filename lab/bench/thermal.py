"""``python -m lab bench thermal``: what the wall heat exchange does to each scene's reading,
and the fast-sorting band.

1. Wall time constants of each tank-method profile's volumes, from their correlations
   (simulator/elements.py).
2. Per profile (method 1, the tank method, with a calibration plan): the noise-free
   reading in the profile's first window at the first and last calibration target, with
   isothermal gas and with the wall model, and the difference. A scene whose difference
   is far below its reading's noise keeps the isothermal model.
3. ``--band``: the sorting gripper's 0.5 s / 74 kPa readings over the stated ranges of
   the parts that carry them, each member fitted again to the two 5 s readings it is
   fitted to (simulator/band.py), against the paper's (Fig. S sortingfaster).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

NAME = "thermal"
HELP = "isothermal against wall heat exchange per scene; the fast-sorting band (--band)"
DESCRIPTION = __doc__

# Fig. S sortingfaster, both orders, (D, mean, sd) kPa at 0.5-0.55 s, 74 kPa
FAST_PAPER = {"a": ((60, 38.21, 0.11), (100, 38.84, 0.07), (80, 38.59, 0.07), (40, 37.44, 0.07)),
              "b": ((100, 39.17, 0.11), (40, 37.33, 0.06), (60, 37.92, 0.07), (80, 38.52, 0.06))}
SLOW_PAPER = {40: (34.13, 0.07), 60: (34.80, 0.07), 80: (35.05, 0.08), 100: (35.36, 0.07)}  # Fig. 4b


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("--band", action="store_true", help="also the fast-sorting band (minutes)")
    p.add_argument("--only", action="append", help="profile names for the per-scene table")
    p.add_argument("--out", help="write the JSON here")
    p.add_argument("--json", action="store_true")


def _scene_rows(only: list[str] | None) -> list[dict[str, Any]]:
    from fluidsense.common.hardware import TankCircuit
    from fluidsense.simulator.band import with_value
    from fluidsense.simulator.circuit import wall_times
    from fluidsense.simulator.timing import step_response, window_mean

    from ..report.common import PROFILES, profile

    rows = []
    for path in sorted(PROFILES.glob("*.yaml")):
        prof = profile(path.stem)
        if only and path.stem not in only:
            continue
        cal, seq = prof.calibration, prof.sequence
        if cal is None or seq.method != "tank" or not isinstance(prof.hardware.circuit, TankCircuit):
            continue
        w = seq.windows[0]
        hw_iso = with_value(prof.hardware, "circuit.thermal.model", "isothermal")
        hw_wall = with_value(prof.hardware, "circuit.thermal.model", "wall")
        row: dict[str, Any] = {"profile": path.stem, "window_s": [w.start_s, w.end_s], "p0_kpa": seq.p0_kpa,
                               "wall_s": {k: round(v, 3) for k, v in wall_times(hw_wall.circuit).items()}}
        for end, value in (("first", cal.values[0]), ("last", cal.values[-1])):
            scene = cal.scene.model_copy(update={cal.target: value})
            iso, wall = (window_mean(step_response(h, scene, seq.p0_kpa, w.end_s + 0.01, dt_s=2e-3), w.start_s,
                                     w.end_s - w.start_s) for h in (hw_iso, hw_wall))
            row[end] = {"target": value, "isothermal_kpa": round(iso, 3), "wall_kpa": round(wall, 3),
                        "difference_kpa": round(wall - iso, 3)}
        rows.append(row)
    return rows


def _band() -> dict[str, Any]:
    from fluidsense.simulator.band import RANGES, band, with_value

    from ..report.common import profile

    hw = with_value(profile("sorting-gripper").hardware, "circuit.thermal.model", "wall")
    members = band(hw)
    lo = {d: min(m.fast_kpa[d] for m in members) for d in members[0].fast_kpa}
    hi = {d: max(m.fast_kpa[d] for m in members) for d in members[0].fast_kpa}
    held = {order: all(lo[d] <= mean <= hi[d] for d, mean, _ in r) for order, r in FAST_PAPER.items()}
    slow_ok = all(abs(m.slow_kpa[d] - mean) <= 2 * sd for m in members for d, (mean, sd) in SLOW_PAPER.items())
    return {"ranges": [{"part": n, "path": p, "low": a, "high": b, "why": why} for n, p, a, b, why in RANGES],
            "members": [{"label": m.label, "compliance_ml_per_kpa": round(m.compliance_ml_per_kpa, 4),
                         "wrap_ratio": round(m.wrap_ratio, 4), "slow_kpa": {d: round(v, 3) for d, v in m.slow_kpa.items()},
                         "fast_kpa": {d: round(v, 3) for d, v in m.fast_kpa.items()}} for m in members],
            "band_kpa": {d: [round(lo[d], 3), round(hi[d], 3)] for d in lo},
            "holds_paper": held, "slow_within_2sd": slow_ok}


def run(args: argparse.Namespace) -> int:
    res: dict[str, Any] = {"scenes": _scene_rows(args.only)}
    if args.band:
        res["band"] = _band()
    if args.out:
        Path(args.out).write_text(json.dumps(res, indent=1) + "\n")
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    for r in res["scenes"]:
        f, la = r["first"], r["last"]
        print(f"{r['profile']:28s} window {r['window_s'][0]:g}-{r['window_s'][1]:g} s  wall {r['wall_s']}  "
              f"wall - isothermal: {f['difference_kpa']:+.3f} kPa (target {f['target']:g}), "
              f"{la['difference_kpa']:+.3f} kPa (target {la['target']:g})")
    if "band" in res:
        b = res["band"]
        for d, (lo, hi) in b["band_kpa"].items():
            paper = [m for r in FAST_PAPER.values() for x, m, _ in r if x == d]
            print(f"D {d} mm: band {lo:.2f}-{hi:.2f} kPa, paper {paper}")
        print(f"band holds (a): {b['holds_paper']['a']}, (b): {b['holds_paper']['b']}; "
              f"5 s readings within 2 sd for every member: {b['slow_within_2sd']}")
    return 0
