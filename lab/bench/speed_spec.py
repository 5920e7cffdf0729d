"""What ``bench speed-accuracy`` measures and how it scores: the paper's scenes and circuits,
and the scoring over them, that the bench and its chart (_speed_chart.py) share."""

from __future__ import annotations

from typing import Any

# the grid, the scoring and its tolerance are the product's (tasks/speed_accuracy.py: one
# code path for `fluidsense chart` and this study); the paper's scenes and circuits are here
from fluidsense.tasks.speed_accuracy import (  # noqa: F401
    DECIDED,
    DECISION_TIMES,
    FINE_STEP_OF_FLOOR,
    FINE_UP_TO_FLOORS,
    decision_times,
    fine_step,
    same_as,
)
from fluidsense.tasks.speed_accuracy import earliest as _earliest
from fluidsense.tasks.speed_accuracy import round_rows as _round  # noqa: F401

SCENES = {
    # scene: (profile, target field, unit, calibration targets, test range)
    "gripper-cylinder": ("pneunet-gripper", "diameter_mm", [40, 55, 70, 85, 100], (40.0, 100.0)),
    "plate-distance": ("pneunet-bending", "height_mm", [0, 10, 20, 30, 40], (0.0, 40.0)),
}
CIRCUITS = {"fast": 0.0, "slow": 5.7e8}


def times_of(rows, scene: str, circuit: str) -> list[float]:
    """The decision times one scene and circuit was evaluated at."""
    return sorted({r["decision_time_s"] for r in rows if r["scene"] == scene and r["circuit"] == circuit})


def ratio_to_floor(earliest_s: float | None, floor: dict[str, float]) -> float | None:
    """The earliest decision against the floor: the time after which a reading no longer
    depends on when it is taken (the settled time of the noise-free step responses)."""
    return None if earliest_s is None else earliest_s / floor["settled_s"]


#: the issue's goal: every scene and circuit decides within this many floors
GOAL_RATIO = 1.5


def earliest(rows, trials: int) -> list[dict[str, Any]]:
    """Per scene, circuit and method: the earliest decision time at which at least DECIDED of
    the cycles are decided with a 95 % error no worse than the 5 s window mean's on the same
    scene and circuit (the paper's sorting reads at 5 s; it publishes no error in mm for it),
    within the sampling tolerance ``same_as(trials)``. ``decision_time_s`` None: not by 5 s."""
    out = []
    for scene in SCENES:
        for circuit in CIRCUITS:
            mine = [r for r in rows if r["scene"] == scene and r["circuit"] == circuit]
            for e in _earliest(mine, trials, DECISION_TIMES[-1], err="err95_mm"):
                out.append({"scene": scene, "circuit": circuit, "method": e["method"],
                            "reference_err95_mm": e["reference_err95"], "decision_time_s": e["decision_time_s"],
                            "err95_mm": e["err95"]})
    return out
