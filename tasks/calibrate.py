"""Calibration and sensing jobs: run cycles over known targets, fit; measure and invert.

On the simulated cell the job places each target itself; on a real cell it asks the
caller (an operator prompt in the CLI) to place it.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from fluidsense.common.errors import FluidsenseError, JobStopped
from fluidsense.common.scenes import TARGETS, EmptyScene, Scene
from fluidsense.common.units import KPA
from fluidsense.controller.ports import TaskPort
from fluidsense.controller.sensing.calibration import (
    FEATURES,
    NEEDS_REFERENCE,
    Calibration,
    CalibrationError,
    feature_value,
)
from fluidsense.controller.sensing.estimate import Estimate, si_unit
from pydantic import TypeAdapter

from .journal import CycleJournal
from .stopping import fault_dict, stopped_message

Place = Callable[[Any], Awaitable[None]]
_SCENE = TypeAdapter(Scene)


def scene_with(scene: Any, target: str, value: float) -> Any:
    data = scene.model_dump() if hasattr(scene, "model_dump") else dict(scene)
    return _SCENE.validate_python({**data, target: value})


async def ensure_reference(port: TaskPort, place: Place, p0_kpa: float | None = None) -> None:
    """A free-air reference cycle at this P0 unless one is stored."""
    profile = port.profile
    p0 = profile.sequence.p0_kpa if p0_kpa is None else p0_kpa
    if port.reference(p0 * KPA) is not None:
        return
    await place(EmptyScene())
    res = await port.run_cycle(p0_kpa=p0, label="reference", store_reference=True)
    if not res.ok:
        raise FluidsenseError(f"reference cycle {res.cycle_id} failed: {res.aborted}")


@dataclass
class CalibrationRun:
    calibration: Calibration
    skipped: list[dict[str, Any]] = field(default_factory=list)  # cycles whose feature was missing


async def calibrate(port: TaskPort, scene: Any, target: str, values: Sequence[float], *, feature: str = "p_eq",
                    fit: str = "linear", cycles: int = 8, drop_first: int = 1, place: Place | None = None,
                    progress: Callable[[int], None] | None = None, seed: int | None = None,
                    journal: CycleJournal | None = None, free_cycles: int = 0) -> CalibrationRun:
    """Run ``cycles`` cycles per target value (dropping the first ``drop_first``, as the
    paper does) and fit ``feature`` against the target; first ``free_cycles`` with nothing
    there (the free reading that tells "no object" apart; same drop). Each finished cycle
    goes into ``journal`` as it completes; cycles already in it (``--resume``) are not run
    again. A run that cannot finish raises JobStopped with what it had done."""
    if feature not in FEATURES:
        raise CalibrationError(f"unknown feature {feature!r}; known: {', '.join(FEATURES)}")
    place = place or port.place
    unit = TARGETS.get(scene.kind, (target, ""))[1]
    entries: list[dict[str, Any]] = list(journal.entries) if journal is not None else []
    total = len(values) * cycles + free_cycles
    try:
        if feature in NEEDS_REFERENCE:
            await ensure_reference(port, place)
        plan: list[tuple[float | None, int]] = [(None, free_cycles)] if free_cycles else []
        for value, n in [*plan, *((v, cycles) for v in values)]:
            done = sum(1 for e in entries if e["value"] == value)
            if done >= n:
                continue
            await place(EmptyScene() if value is None else scene_with(scene, target, value))
            label = "free" if value is None else f"{target}={value:g}"
            for k in range(done, n):
                res = await port.run_cycle(label=label)
                if not res.ok:
                    raise FluidsenseError(f"calibration cycle {res.cycle_id} ({label}) ended: {res.aborted}")
                entry = {"value": None if value is None else float(value), "k": k, "cycle_id": res.cycle_id,
                         "y": feature_value(res, feature)}
                entries.append(entry)
                if journal is not None:
                    journal.add(entry)
                if progress is not None:
                    progress(1)
    except (CalibrationError, asyncio.CancelledError, KeyboardInterrupt):
        raise
    except FluidsenseError as exc:
        kept = f"; finished cycles are kept in {journal.path}: run again with --resume" if journal else ""
        partial = {"completed": False, "cycles_done": len(entries), "cycles_total": total,
                   "journal": None if journal is None else str(journal.path), "fault": fault_dict(port),
                   "error": f"{type(exc).__name__}: {exc}"}
        raise JobStopped(stopped_message("calibration", port, exc, f"{len(entries)} of {total} cycles") + kept,
                         partial, partial["fault"]) from exc
    used = [e for e in entries if e["k"] >= drop_first]
    free_y = [e["y"] for e in used if e["value"] is None and e["y"] is not None]
    used = [e for e in used if e["value"] is not None]
    skipped = [{"cycle_id": e["cycle_id"], target: e["value"]} for e in used if e["y"] is None]
    points = [(e["value"], e["y"]) for e in used if e["y"] is not None]
    profile = port.profile
    seq = profile.sequence
    window = (seq.flow_window if feature == "v_eq" else seq.windows[0]).model_dump()
    cal = Calibration.fit_points(
        [x for x, _ in points], [y for _, y in points], fit, profile=profile.name, method=seq.method,
        feature=feature, feature_unit=FEATURES[feature][1], scene=scene.model_dump(), target=target,
        target_unit=unit, window=window, seed=seed, cycles=cycles, drop_first=drop_first, free_y=free_y,
        session_rel_sd=profile.session_rel_sd)
    return CalibrationRun(cal, skipped)


@dataclass
class Sensing:
    estimate: Estimate
    values: list[float]  # the feature of every cycle, edge units
    truth: float | None  # the scene's target (simulated cell), edge units
    target_unit: str = ""
    feature_unit: str = ""

    def to_dict(self) -> dict[str, Any]:
        """Edge units. ``status`` says whether there is a value: ``ok``, ``no_object``
        (nothing there) or ``out_of_range`` (``bound`` is the nearest calibrated one)."""
        e = self.estimate
        _, factor = si_unit(self.target_unit)

        def edge(v: float | None) -> float | None:
            return None if v is None else v / factor

        ok = e.status == "ok"
        return {
            "quantity": e.quantity, "status": e.status, "object": e.status != "no_object",
            "estimate": edge(e.value), "interval": [edge(e.lo), edge(e.hi)], "coverage": e.coverage,
            "interval95": [edge(e.lo), edge(e.hi)] if ok and e.coverage == 0.95 else None,
            "bound": edge(e.bound), "unit": self.target_unit, "detail": e.detail, "feature": e.feature,
            "measured": None if not self.values else sum(self.values) / len(self.values),
            "feature_unit": self.feature_unit, "extrapolated": e.status == "out_of_range",
            "cycles": len(self.values), "measurements": self.values, "truth": self.truth,
            "error": None if self.truth is None or not ok else edge(e.value) - self.truth,
            "covered": None if self.truth is None or not ok else edge(e.lo) <= self.truth <= edge(e.hi),
        }


async def sense(port: TaskPort, cal: Calibration, scene: Any | None = None, cycles: int = 1,
                place: Place | None = None) -> Sensing:
    """Measure ``cycles`` cycles (averaged) and say what the calibration makes of them:
    a value with its interval, no object, or out of range."""
    place = place or port.place
    profile = port.profile
    if profile.name != cal.profile:
        raise CalibrationError(f"calibration is for profile {cal.profile!r}, the cell runs {profile.name!r}")
    if cal.feature in NEEDS_REFERENCE:
        await ensure_reference(port, place)
    if scene is not None:
        await place(scene)
    values: list[float] = []
    missing = 0
    for _ in range(cycles):
        try:
            res = await port.run_cycle(label="sense")
            if not res.ok:
                raise FluidsenseError(f"sensing cycle {res.cycle_id} ended: {res.aborted}")
        except FluidsenseError as exc:
            partial = {"completed": False, "cycles_done": len(values), "cycles_total": cycles,
                       "measurements": values, "fault": fault_dict(port), "error": f"{type(exc).__name__}: {exc}"}
            raise JobStopped(stopped_message("sensing", port, exc, f"{len(values)} of {cycles} cycles"), partial,
                             partial["fault"]) from exc
        y = feature_value(res, cal.feature)
        if y is None:
            missing += 1  # no contact: this cycle says "nothing there"
        else:
            values.append(y)
    scale = FEATURES[cal.feature][2]
    if missing > len(values):  # most cycles saw nothing
        est = cal.estimate(None, n_measurements=cycles)
    else:
        est = cal.estimate(sum(values) / len(values) / scale, n_measurements=len(values))
    truth = await _truth(port, scene, cal.target)
    return Sensing(est, values, truth, cal.target_unit, cal.feature_unit)


async def _truth(port: TaskPort, scene: Any | None, target: str) -> float | None:
    """The target's true value from the scene's geometry (simulated cell), not from any
    measurement."""
    if scene is not None and hasattr(scene, target):
        return float(getattr(scene, target))
    truth = await port.truth() if port.simulated else None
    value = None if truth is None else truth.get(target)
    return float(value) if isinstance(value, (int, float)) else None
