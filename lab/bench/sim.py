"""``python -m lab bench sim``: how much faster than real time the simulated cell runs."""

from __future__ import annotations

import argparse
import asyncio
import json
import time

import numpy as np

NAME = "sim"
HELP = "virtual-time throughput of the simulated cell (full gripper cycles at 1 kHz)"
DESCRIPTION = ("Run full gripper cycles (50 s of sample time each, 1 kHz) in virtual time and report how many "
               "times faster than real time they ran: the cell alone, and the cell with the whole controller.")


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("--cycles", type=int, default=10, help="cycles per measurement (default 10)")
    p.add_argument("--config", "-c", help="cell config with driver: sim (default: config/cell-sim.yaml)")
    p.add_argument("--batches", action="store_true",
                   help="build the 100 ms pressure batches as a daemon with a publisher does (sent nowhere)")
    p.add_argument("--json", action="store_true")


async def _controller_cycles(cfg, n: int, batches: bool = False) -> list[float]:
    from fluidsense.daemon import app

    walls = []
    async with app.controller(cfg) as ctrl:
        ctrl.telemetry.batches = batches
        for _ in range(n):
            t0 = time.perf_counter()
            await ctrl.run_cycle()
            walls.append(time.perf_counter() - t0)
    return walls


async def _cell_cycles(cfg, n: int) -> tuple[list[float], float]:
    """The cell alone: the sequencer's valve schedule replayed without the controller."""
    from fluidsense.drivers.registry import build_backend

    seq = cfg.profile.sequence
    period = seq.charge_s + seq.isolate_s + seq.actuate_s + seq.vent_s
    backend = build_backend(cfg.driver, cfg.profile.hardware)
    walls = []
    async with backend:
        src, valves = backend.source, backend.valves
        t = 0.0
        for _ in range(n):
            t0 = time.perf_counter()
            schedule = [(t, "supply", True), (t + seq.charge_s, "supply", False),
                        (t + seq.charge_s + seq.isolate_s, "actuate", True),
                        (t + seq.charge_s + seq.isolate_s + seq.actuate_s, "actuate", False)]
            await backend.regulator.set_setpoint(seq.p0_kpa * 1e3, t)
            end = t + period
            while True:
                blk = await src.read_block()
                while schedule and blk.t_end >= schedule[0][0]:
                    _, name, state = schedule.pop(0)
                    await valves.set(name, state, blk.t_end)
                if blk.t_end >= end:
                    break
            t = blk.t_end
            walls.append(time.perf_counter() - t0)
    return walls, period


def run(args: argparse.Namespace) -> int:
    from fluidsense.daemon import app

    cfg = app.load(args.config, {"driver": {"clock": "virtual"}})
    seq = cfg.profile.sequence
    period = seq.charge_s + seq.isolate_s + seq.actuate_s + seq.vent_s
    cell, _ = asyncio.run(_cell_cycles(cfg, args.cycles))
    full = asyncio.run(_controller_cycles(cfg, args.cycles, args.batches))

    def summary(walls: list[float]) -> dict:
        w = np.array(walls)
        return {"cycles": len(w), "wall_s_p50": float(np.median(w)), "wall_s_max": float(w.max()),
                "speedup_p50": period / float(np.median(w)), "speedup_min": period / float(w.max())}

    out = {"cycle_s": period, "rate_hz": cfg.driver.rate_hz, "block_size": cfg.driver.block_size,
           "pressure_batches": args.batches,
           "cell_only": summary(cell), "with_controller": summary(full)}
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        for key, label in (("cell_only", "cell alone"), ("with_controller", "cell + controller")):
            s = out[key]
            print(f"{label:>18}: {period:.0f} s cycle in {s['wall_s_p50'] * 1e3:.0f} ms (median of {s['cycles']}), "
                  f"{s['speedup_p50']:.0f}x real time (worst {s['speedup_min']:.0f}x)")
    return 0
