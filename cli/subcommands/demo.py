"""``fluidsense demo``: size sensing on the simulated gripper (paper Fig. 1f)."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from typing import Any

from fluidsense.common.errors import FluidsenseError

from ._common import setup_logging

DEMO_DIAMETERS: list[float | None] = [None, 20, 40, 60, 80, 100]


def register(sub) -> None:
    p = sub.add_parser("demo", help="size sensing on the simulated gripper (paper Fig. 1f)",
                       description="Grip nothing and cylinders of D = 20, 40, 60, 80, 100 mm in virtual time, "
                       "6 cycles each (the last 5 used), P_eq over 4-5 s after opening; print P_eq per D "
                       "and the linear fit.")
    p.add_argument("--config", "-c", help="cell config YAML with driver: sim (default: config/cell-sim.yaml)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--seed", type=int, default=1, help="random seed of the simulated cell (default 1)")
    p.add_argument("--cycles", type=int, default=6, help="cycles per object, first dropped (default 6)")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from fluidsense.daemon import app
    from fluidsense.tasks.size_survey import size_survey

    overrides: dict[str, Any] = {"driver": {"clock": "virtual", "seed": args.seed}}
    cfg = app.load(args.config, overrides)
    setup_logging(cfg.log_level, quiet=True)
    if cfg.driver.samples_seed() is None:
        raise FluidsenseError("the demo runs on the simulated cell: use a config with driver: sim")

    def progress(line: str) -> None:
        if not args.json:
            print(f"  {line}", file=sys.stderr, flush=True)

    async def job():
        async with app.controller(cfg) as ctrl:
            return await size_survey(ctrl.task_port, DEMO_DIAMETERS, cycles=args.cycles, drop_first=1,
                                     progress=progress)

    if not args.json:
        w = cfg.profile.sequence.windows[0]
        print(f"fluidsense demo: {cfg.profile.name}, tank {cfg.profile.circuit.tank_l} L at "
              f"{cfg.profile.sequence.p0_kpa} kPa, {args.cycles} cycles per object (first dropped), "
              f"P_eq over {w.start_s:g}-{w.end_s:g} s after opening, virtual time, seed {args.seed}",
              file=sys.stderr)
    res = asyncio.run(job())
    out = res.to_dict()
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    print()
    print(f"{'object':>12} | {'P_eq (kPa)':>10} | {'sd (kPa)':>8} | cycles")
    print(f"{'-' * 12}-+-{'-' * 10}-+-{'-' * 8}-+-------")
    for p in out["points"]:
        name = "nothing" if p["diameter_mm"] is None else f"D {p['diameter_mm']:g} mm"
        print(f"{name:>12} | {p['p_eq_kpa']:10.3f} | {p['p_sd_kpa']:8.3f} | {p['cycles']}")
    print()
    print(f"linear fit over D >= {out['fit']['min_diameter_mm']:g} mm: P_eq = "
          f"{out['fit']['intercept_kpa']:.3f} kPa + {out['slope_kpa_per_mm']:.4f} kPa/mm * D   "
          f"(r^2 = {out['r2']:.4f}; paper: about 0.04 kPa/mm)")
    print(f"{out['cycles_run']} cycles, {out['virtual_s']:.0f} s of sample time in {out['wall_s']:.2f} s "
          f"wall ({out['speedup']:.0f}x real time, {out['wall_ms_per_cycle']:.0f} ms per cycle)")
    return 0
