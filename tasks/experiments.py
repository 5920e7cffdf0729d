"""Experiment protocols shared by the reproduction report and the benchmarks: run
cycles over scenes and keep every result (calibration and sensing keep only features)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from fluidsense.common.errors import FluidsenseError, SequenceError
from fluidsense.common.scenes import EmptyScene
from fluidsense.controller.config import CellConfig, Profile
from fluidsense.controller.cycles.analysis import CycleResult
from fluidsense.controller.ports import TaskPort
from fluidsense.drivers.registry import SimDriverConfig, build_backend

from .calibrate import scene_with


@dataclass
class Run:
    scene: Any
    target: float | None
    result: CycleResult
    truth: dict[str, Any]


def sim_cell(profile: Profile, seed: int, block_size: int = 10) -> tuple[CellConfig, Any]:
    """A virtual-time simulated cell for a profile (config and backend)."""
    cfg = CellConfig(driver=SimDriverConfig(clock="virtual", seed=seed, block_size=block_size), profile=profile)
    return cfg, build_backend(cfg.driver, profile.hardware)


async def reference(port: TaskPort, p0_kpa: float | None = None) -> CycleResult:
    await port.place(EmptyScene())
    res = await port.run_cycle(p0_kpa=p0_kpa, label="reference", store_reference=True)
    if not res.ok:
        raise FluidsenseError(f"reference cycle failed: {res.aborted}")
    return res


async def _truth_at_window(port: TaskPort) -> dict[str, Any] | None:
    """What the simulated cell knows in the middle of the first measurement window (the
    force on a plate, an indentation: a bench instrument's reading at the moment the
    pressure is measured, from the plant's own state, not from the sensor)."""
    if not port.simulated:
        return None
    profile = port.profile
    try:
        w = profile.sequence.windows[0]
        await port.wait_after_open(0.5 * (w.start_s + w.end_s))
    except SequenceError:  # the cycle ended before its valve opened: nothing to read
        return None
    return await port.truth()


async def sweep(port: TaskPort, scene: Any, target: str | None, values: Sequence[float | None], cycles: int = 1,
                drop_first: int = 0, p0_kpa: float | None = None,
                on_cycle: Callable[[], None] | None = None) -> list[Run]:
    """``cycles`` cycles for each target value (the first ``drop_first`` not kept).
    ``target`` None with ``values`` of scenes runs those scenes as given."""
    runs = []
    for value in values:
        sc = value if target is None else scene_with(scene, target, value)
        await port.place(sc)
        for k in range(cycles):
            pending = await port.start_cycle(p0_kpa=p0_kpa)
            truth = await _truth_at_window(port)
            res = await pending
            if on_cycle is not None:
                on_cycle()
            if not res.ok:
                raise FluidsenseError(f"cycle {res.cycle_id} on {sc} failed: {res.aborted}")
            if k >= drop_first:
                tv = None if target is None else float(value)
                runs.append(Run(sc, tv, res, truth))
    return runs
