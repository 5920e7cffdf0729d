"""``python -m lab bench faults``: every fault injected many times, detected and vented?

Each fault kind is injected at random moments of a cycle on the simulated cell (virtual
time; the loop overrun, which only exists in real time, in real time by blocking the
loop; ``internal``, an exception raised inside the sample loop). For each: whether the
supervisor reported it (within two cycles: a leak injected while the actuator vents only
shows once it is held again), how long after the first bad sample the vent was commanded
(in samples; target: within one block), and how long the physics took to make it
visible. Then clean cycles, counting false alarms. With ``--box-runs N`` (N > 0), what
only the control box can vent, against ``fluidsense simcell`` (see _box_faults.py):
a killed daemon, a pulled cable, a cable back in, and SIGTERM.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import time
from typing import Any

import numpy as np

NAME = "faults"
HELP = "fault injection: detection, vent latency, false alarms"
DESCRIPTION = __doc__
SEED = 1
EXPECTED = {"over_pressure": {"over_pressure"}, "leak": {"leak"}, "sensor_nan": {"sensor_nan"},
            "sensor_stuck": {"sensor_stuck"}, "sensor_range": {"sensor_range"}, "no_data": {"no_data"},
            "link_lost": {"link_lost"}, "protective_stop": {"protective_stop"}, "overrun": {"overrun"},
            "internal": {"internal"}}


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("--injections", type=int, default=20, help="per fault kind (default 20)")
    p.add_argument("--clean-cycles", type=int, default=1000, help="clean cycles for false alarms (default 1000)")
    p.add_argument("--overrun-injections", type=int, default=5, help="real-time loop stalls (default 5)")
    p.add_argument("--box-runs", type=int, default=5,
                   help="per box scenario against fluidsense simcell, real time (default 5; 0 skips them)")
    p.add_argument("--seed", type=int, default=SEED)
    p.add_argument("--json", action="store_true")


def profile():
    from ..report.common import profile as load

    prof = load("pneunet-gripper")
    seq = prof.sequence.model_copy(update={"charge_s": 2.0, "isolate_s": 1.0, "actuate_s": 8.0, "vent_s": 2.0})
    return prof.model_copy(update={"sequence": seq, "calibration": None})


def _cfg(seed: int, clock: str = "virtual"):
    from fluidsense.controller.config import CellConfig
    from fluidsense.drivers.registry import SimDriverConfig

    return CellConfig(driver=SimDriverConfig(clock=clock, seed=seed), profile=profile())


async def inject_once(ctrl, kind: str, t_offset: float) -> dict[str, Any]:
    """Inject ``kind`` ``t_offset`` s into a fresh cycle; run until a fault or two cycles."""
    cell = ctrl.backend.sim
    rate = ctrl.backend.source.rate_hz
    fut = await ctrl.start_cycle()
    t_inj = ctrl.now + t_offset
    if kind == "internal":
        _raise_in_loop(ctrl, t_inj)
    else:
        cell.inject(kind, t_inj)
    for _ in range(2):
        try:
            await fut
        except Exception:  # noqa: BLE001 - the fault fails the cycle's future: that is the point
            pass
        if ctrl.fault is not None:
            break
        fut = await ctrl.start_cycle()
    out = {"kind": kind, "t_inj": t_inj, "detected": False}
    if ctrl.latch.last_vent is not None and ctrl.fault is not None:
        fault, t_vent = ctrl.latch.last_vent
        out.update(detected=fault.kind in EXPECTED[kind], reported=fault.kind,
                   vent_latency_samples=int(round((t_vent - fault.t) * rate)),
                   detect_delay_s=max(fault.t - t_inj, 0.0), vented=ctrl.backend.valves.in_safe_state)
    cell.clear_faults()
    await ctrl.wait(3.0)  # the repaired cell vents (still latched, so no new fault) ...
    ctrl.reset()  # ... then the operator resets
    return out


def _raise_in_loop(ctrl, t: float) -> None:
    """A bug in the sample loop at sample time ``t`` (once): the supervisor's check raises."""
    check = ctrl.supervisor.check

    def broken(block, **kwargs):
        if block.t_end >= t:
            ctrl.supervisor.check = check
            raise RuntimeError("injected: a bug in the sample loop")
        return check(block, **kwargs)

    ctrl.supervisor.check = broken


async def _injections(kinds, n: int, seed: int) -> list[dict[str, Any]]:
    from fluidsense.common.scenes import CylinderScene
    from fluidsense.controller.service import Controller
    from fluidsense.drivers.registry import build_backend

    rng = np.random.default_rng(seed)
    cfg = _cfg(seed)
    seq = cfg.profile.sequence
    cycle_s = seq.charge_s + seq.isolate_s + seq.actuate_s + seq.vent_s
    out = []
    async with Controller(cfg, build_backend(cfg.driver, cfg.profile.hardware)) as ctrl:
        await ctrl.scene.place(CylinderScene(diameter_mm=60))
        for kind in kinds:
            for _ in range(n):
                out.append(await inject_once(ctrl, kind, float(rng.uniform(0, cycle_s))))
    return out


async def _clean(cycles: int, seed: int) -> tuple[int, list[str]]:
    from fluidsense.common.scenes import CylinderScene, EmptyScene
    from fluidsense.controller.service import Controller
    from fluidsense.drivers.registry import build_backend

    rng = np.random.default_rng(seed + 7)
    cfg = _cfg(seed + 1)
    alarms = []
    async with Controller(cfg, build_backend(cfg.driver, cfg.profile.hardware)) as ctrl:
        for k in range(cycles):
            if k % 10 == 0:
                d = float(rng.uniform(20, 110))
                await ctrl.scene.place(EmptyScene() if d < 30 else CylinderScene(diameter_mm=d))
            await ctrl.run_cycle()
            if ctrl.fault is not None:
                alarms.append(f"{ctrl.fault.kind}: {ctrl.fault.detail}")
                ctrl.reset()
    return cycles, alarms


async def _overrun(n: int, seed: int) -> list[dict[str, Any]]:
    """Real time: a sink that blocks the loop for 0.5 s, once per cycle."""
    from fluidsense.common.errors import FaultError
    from fluidsense.controller.service import Controller, Sink
    from fluidsense.drivers.registry import build_backend

    class Stall(Sink):
        def __init__(self):
            self.at: float | None = None

        def on_block(self, block) -> None:
            if self.at is not None and block.t_end >= self.at:
                self.at = None
                time.sleep(0.5)  # deliberately blocks the event loop: the overrun under test

    cfg = _cfg(seed, clock="realtime")
    rng = np.random.default_rng(seed + 3)
    stall = Stall()
    out = []
    async with Controller(cfg, build_backend(cfg.driver, cfg.profile.hardware)) as ctrl:
        ctrl.add_sink(stall)
        await ctrl.wait(0.3)
        for _ in range(n):
            stall.at = ctrl.now + float(rng.uniform(0.1, 0.5))
            give_up = stall.at + 2.0  # the sink clears stall.at when it stalls
            try:  # the fault releases this wait with the fault
                while ctrl.fault is None and ctrl.now < give_up:
                    await ctrl.wait(0.05)
            except FaultError:
                pass
            rec = {"kind": "overrun", "detected": False}
            if ctrl.fault is not None and ctrl.latch.last_vent is not None:
                fault, t_vent = ctrl.latch.last_vent
                rec.update(detected=fault.kind == "overrun", reported=fault.kind,
                           vent_latency_samples=int(round((t_vent - fault.t) * ctrl.backend.source.rate_hz)),
                           detect_delay_s=0.0, vented=ctrl.backend.valves.in_safe_state)
            out.append(rec)
            ctrl.reset()
            await ctrl.wait(0.3)
    return out


def run_bench(injections: int = 20, clean_cycles: int = 1000, overrun_injections: int = 5,
              seed: int = SEED, box_runs: int = 0) -> dict[str, Any]:
    from fluidsense.simulator.cell import FAULTS

    from ._box_faults import run_box_faults

    t0 = time.perf_counter()
    kinds = [*FAULTS, "internal"]
    recs = asyncio.run(_injections(kinds, injections, seed))
    if overrun_injections:
        recs += asyncio.run(_overrun(overrun_injections, seed))
    cycles, alarms = asyncio.run(_clean(clean_cycles, seed))
    faults = []
    for kind in [*kinds, *(["overrun"] if overrun_injections else [])]:
        rs = [r for r in recs if r["kind"] == kind]
        lat = [r["vent_latency_samples"] for r in rs if r["detected"]]
        delay = [r["detect_delay_s"] for r in rs if r["detected"]]
        faults.append({"fault": kind, "injections": len(rs),
                       "detected_fraction": sum(r["detected"] for r in rs) / len(rs),
                       "vent_latency_samples_max": max(lat) if lat else None,
                       "detect_delay_s_max": max(delay) if delay else None,
                       "vented_fraction": sum(bool(r.get("vented")) for r in rs) / len(rs),
                       "misreported": sorted({r["reported"] for r in rs if r.get("reported") and not r["detected"]})})
    box = run_box_faults(box_runs) if box_runs > 0 else []
    return {"faults": faults, "clean_cycles": cycles, "false_alarms": len(alarms), "false_alarm_kinds": alarms[:10],
            "block_size": 10, "box": box, "wall_s": time.perf_counter() - t0}


def run(args: argparse.Namespace) -> int:
    res = run_bench(args.injections, args.clean_cycles, args.overrun_injections, args.seed, args.box_runs)
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    for f in res["faults"]:
        print(f"{f['fault']:>16}: {f['injections']} injected, {100 * f['detected_fraction']:.0f} % detected, vent within "
              f"{f['vent_latency_samples_max']} samples, physics delay up to {f['detect_delay_s_max']} s")
    for b in res["box"]:
        print(f"{b['scenario']:>16} ({b['driver']}): {b['runs'] - b['failed']}/{b['runs']} ran, latency median "
              f"{b['latency_s_median']} s, max {b['latency_s_max']} s" + (f"; failures: {b['failures']}" if b["failed"] else ""))
    print(f"clean cycles {res['clean_cycles']}: {res['false_alarms']} false alarms; {res['wall_s']:.0f} s")
    return 0
