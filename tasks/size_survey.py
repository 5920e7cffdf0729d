"""Size survey: the paper's gripper-on-cylinders calibration (Fig. 1f).

For each object (nothing, then cylinders of diameter D) run N cycles, drop the first
(the paper used the last 5 of 6), average P_eq over the profile's first window, and
fit P_eq against D over the grasping range (the paper fitted D = 40..100 mm).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from fluidsense.common.errors import CommandError, FluidsenseError
from fluidsense.common.scenes import CylinderScene, EmptyScene
from fluidsense.controller.ports import TaskPort
from scipy import stats


@dataclass
class SurveyPoint:
    diameter_mm: float | None  # None: nothing gripped
    values_kpa: list[float]

    @property
    def p_eq_kpa(self) -> float:
        return float(np.mean(self.values_kpa))

    @property
    def p_sd_kpa(self) -> float:
        return float(np.std(self.values_kpa, ddof=1)) if len(self.values_kpa) > 1 else 0.0

    def to_dict(self) -> dict[str, Any]:
        return {"diameter_mm": self.diameter_mm, "p_eq_kpa": self.p_eq_kpa, "p_sd_kpa": self.p_sd_kpa,
                "cycles": len(self.values_kpa)}


@dataclass
class SurveyResult:
    points: list[SurveyPoint]
    fit_min_mm: float
    slope_kpa_per_mm: float
    intercept_kpa: float
    r2: float
    cycles_run: int
    virtual_s: float
    wall_s: float
    window: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "points": [p.to_dict() for p in self.points],
            "fit": {"min_diameter_mm": self.fit_min_mm, "slope_kpa_per_mm": self.slope_kpa_per_mm,
                    "intercept_kpa": self.intercept_kpa, "r2": self.r2},
            "slope_kpa_per_mm": self.slope_kpa_per_mm, "r2": self.r2,
            "window_s": self.window, "cycles_run": self.cycles_run,
            "virtual_s": self.virtual_s, "wall_s": self.wall_s,
            "wall_ms_per_cycle": 1e3 * self.wall_s / max(self.cycles_run, 1),
            "speedup": self.virtual_s / self.wall_s if self.wall_s > 0 else None,
        }


async def size_survey(port: TaskPort, diameters_mm: Sequence[float | None], cycles: int = 6,
                      drop_first: int = 1, fit_min_mm: float = 40.0,
                      progress: Callable[[str], None] | None = None) -> SurveyResult:
    if cycles - drop_first < 2:
        raise CommandError(f"need at least 2 cycles after dropping {drop_first}; got {cycles}")
    t_virtual0, t_wall0 = port.now(), time.perf_counter()
    points: list[SurveyPoint] = []
    for d in diameters_mm:
        await port.place(EmptyScene() if d is None else CylinderScene(diameter_mm=d))
        values = []
        for k in range(cycles):
            res = await port.run_cycle(label=f"D={d}" if d is not None else "empty")
            if not res.ok:
                raise FluidsenseError(f"cycle {res.cycle_id} on D={d} failed: {res.aborted}")
            if k >= drop_first:
                values.append(res.p_eq / 1e3)
        points.append(SurveyPoint(d, values))
        if progress is not None:
            label = "nothing" if d is None else f"D = {d:g} mm"
            progress(f"{label}: P_eq {points[-1].p_eq_kpa:.3f} +- {points[-1].p_sd_kpa:.3f} kPa")
    fit_pts = [p for p in points if p.diameter_mm is not None and p.diameter_mm >= fit_min_mm]
    if len(fit_pts) >= 2:
        lr = stats.linregress([p.diameter_mm for p in fit_pts], [p.p_eq_kpa for p in fit_pts])
        slope, intercept, r2 = float(lr.slope), float(lr.intercept), float(lr.rvalue ** 2)
    else:
        slope = intercept = r2 = float("nan")
    profile = port.profile
    w = profile.sequence.windows[0]
    return SurveyResult(points, fit_min_mm, slope, intercept, r2, cycles * len(diameters_mm),
                        port.now() - t_virtual0, time.perf_counter() - t_wall0,
                        {"start_s": w.start_s, "end_s": w.end_s})
