"""Calibration and sensing jobs: run cycles over known targets, fit; measure and invert.

On the simulated cell the job places each target itself; on a real cell it asks the
caller (an operator prompt in the CLI) to place it.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from pydantic import TypeAdapter

from controller.calibration import (FEATURES, NEEDS_REFERENCE, Calibration, CalibrationError, Estimate,
                                    feature_value)
from controller.service import Controller
from drivers.errors import FluidsenseError
from drivers.scenes import TARGETS, EmptyScene, Scene

Place = Callable[[Any], Awaitable[None]]
_SCENE = TypeAdapter(Scene)


def scene_with(scene: Any, target: str, value: float) -> Any:
    data = scene.model_dump() if hasattr(scene, "model_dump") else dict(scene)
    return _SCENE.validate_python({**data, target: value})


async def ensure_reference(ctrl: Controller, place: Place, p0_kpa: float | None = None) -> None:
    """A free-air reference cycle at this P0 unless one is stored."""
    p0 = ctrl.profile.sequence.p0_kpa if p0_kpa is None else p0_kpa
    if round(p0, 3) in ctrl.references:
        return
    await place(EmptyScene())
    res = await ctrl.run_cycle(p0_kpa=p0, label="reference", store_reference=True)
    if not res.ok:
        raise FluidsenseError(f"reference cycle {res.cycle_id} failed: {res.aborted}")


@dataclass
class CalibrationRun:
    calibration: Calibration
    skipped: list[dict[str, Any]] = field(default_factory=list)  # cycles whose feature was missing


async def calibrate(ctrl: Controller, scene: Any, target: str, values: Sequence[float], *, feature: str = "p_eq",
                    fit: str = "linear", cycles: int = 8, drop_first: int = 1, place: Place | None = None,
                    progress: Callable[[int], None] | None = None, seed: int | None = None) -> CalibrationRun:
    """Run ``cycles`` cycles per target value (dropping the first ``drop_first``, as the
    paper does) and fit ``feature`` against the target."""
    if feature not in FEATURES:
        raise CalibrationError(f"unknown feature {feature!r}; known: {', '.join(FEATURES)}")
    place = place or ctrl.set_scene
    unit = TARGETS.get(scene.kind, (target, ""))[1]
    if feature in NEEDS_REFERENCE:
        await ensure_reference(ctrl, place)
    xs, ys, skipped = [], [], []
    for value in values:
        await place(scene_with(scene, target, value))
        for k in range(cycles):
            res = await ctrl.run_cycle(label=f"{target}={value:g}")
            if progress is not None:
                progress(1)
            if not res.ok:
                raise FluidsenseError(f"calibration cycle {res.cycle_id} at {target}={value} failed: {res.aborted}")
            if k < drop_first:
                continue
            y = feature_value(res, feature)
            if y is None:
                skipped.append({"cycle_id": res.cycle_id, target: value})
                continue
            xs.append(float(value))
            ys.append(y)
    seq = ctrl.profile.sequence
    window = (seq.flow_window if feature == "v_eq" else seq.windows[0]).model_dump()
    cal = Calibration.fit_points(
        xs, ys, fit, profile=ctrl.profile.name, method=seq.method, feature=feature,
        feature_unit=FEATURES[feature][1], scene=scene.model_dump(), target=target, target_unit=unit,
        window=window, seed=seed, cycles=cycles, drop_first=drop_first)
    return CalibrationRun(cal, skipped)


@dataclass
class Sensing:
    estimate: Estimate
    values: list[float]
    truth: float | None

    def to_dict(self) -> dict[str, Any]:
        d = self.estimate.to_dict()
        d["cycles"] = len(self.values)
        d["measurements"] = self.values
        d["truth"] = self.truth
        d["error"] = None if self.truth is None else d["estimate"] - self.truth
        return d


async def sense(ctrl: Controller, cal: Calibration, scene: Any | None = None, cycles: int = 1,
                place: Place | None = None) -> Sensing:
    """Measure ``cycles`` cycles (averaged) and invert the calibration."""
    place = place or ctrl.set_scene
    if ctrl.profile.name != cal.profile:
        raise CalibrationError(f"calibration is for profile {cal.profile!r}, the cell runs {ctrl.profile.name!r}")
    if cal.feature in NEEDS_REFERENCE:
        await ensure_reference(ctrl, place)
    if scene is not None:
        await place(scene)
    values = []
    for _ in range(cycles):
        res = await ctrl.run_cycle(label="sense")
        if not res.ok:
            raise FluidsenseError(f"sensing cycle {res.cycle_id} failed: {res.aborted}")
        y = feature_value(res, cal.feature)
        if y is None:
            raise CalibrationError(f"cycle {res.cycle_id} gave no {cal.feature} (no contact detected?)")
        values.append(y)
    est = cal.invert(sum(values) / len(values), n_measurements=len(values))
    truth = None
    if scene is not None and hasattr(scene, cal.target):
        truth = getattr(scene, cal.target)
    return Sensing(est, values, truth)
