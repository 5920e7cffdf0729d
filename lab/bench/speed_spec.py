"""What ``bench speed-accuracy`` measures and how it scores: the tables and the scoring that
the bench and its chart (_speed_chart.py) share."""

from __future__ import annotations

from typing import Any

import numpy as np

# the coarse grid every scene shares (the per-pair tables and the sorting line use it)
DECISION_TIMES = (0.1, 0.2, 0.3, 0.5, 1.0, 2.0, 5.0)
# ... and, per scene and circuit, a fine grid from the farthest contact (nothing decides before
# it) to twice the settled time, in steps of 5 % of the settled time: it resolves the ratio of
# the earliest decision to that floor to 0.05, which the coarse grid cannot (the plate on the
# fast circuit settles at about 0.15 s; 0.1 s steps give it ratios of 0.7, 1.4, 2.0)
FINE_STEP_OF_FLOOR = 0.05
FINE_UP_TO_FLOORS = 2.0
SCENES = {
    # scene: (profile, target field, unit, calibration targets, test range)
    "gripper-cylinder": ("pneunet-gripper", "diameter_mm", [40, 55, 70, 85, 100], (40.0, 100.0)),
    "plate-distance": ("pneunet-bending", "height_mm", [0, 10, 20, 30, 40], (0.0, 40.0)),
}
CIRCUITS = {"fast": 0.0, "slow": 5.7e8}
DECIDED = 0.95  # a method "decides" at t_d when at least this fraction of cycles has an estimate


def fine_step(floor: dict[str, float]) -> float:
    """The fine grid's step for one floor, rounded to the ms."""
    return max(1e-3, round(FINE_STEP_OF_FLOOR * floor["settled_s"], 3))


def decision_times(floor: dict[str, float]) -> tuple[float, ...]:
    """The grid of one scene and circuit: the coarse one and the fine one around its floor
    (``floor``: the bench's ``contact_s`` and ``settled_s``), in seconds rounded to the ms."""
    step = fine_step(floor)
    first = np.ceil(floor["contact_s"] / step - 1e-9) * step
    last = min(FINE_UP_TO_FLOORS * floor["settled_s"], DECISION_TIMES[-1])
    fine = [t for t in np.arange(first, last + step / 2, step) if t <= last + 1e-9]
    return tuple(sorted({round(float(t), 3) for t in (*DECISION_TIMES, *fine)}))


def times_of(rows, scene: str, circuit: str) -> list[float]:
    """The decision times one scene and circuit was evaluated at."""
    return sorted({r["decision_time_s"] for r in rows if r["scene"] == scene and r["circuit"] == circuit})


def ratio_to_floor(earliest_s: float | None, floor: dict[str, float]) -> float | None:
    """The earliest decision against the floor: the time after which a reading no longer
    depends on when it is taken (the settled time of the noise-free step responses)."""
    return None if earliest_s is None else earliest_s / floor["settled_s"]


#: the issue's goal: every scene and circuit decides within this many floors
GOAL_RATIO = 1.5


def _round(rows):
    out = []
    for r in rows:
        out.append({k: (float(f"{v:.4g}") if isinstance(v, float) else v) for k, v in r.items()})
    return out


def same_as(trials: int) -> float:
    """Relative tolerance for "no worse than": one standard error of the difference of two
    95th percentiles of |error| estimated from ``trials`` cycles each (normal errors: the
    percentile's own relative standard error is sqrt(0.05 * 0.95 / n) / (2 phi(1.96) 1.96))."""
    phi = np.exp(-1.96**2 / 2) / np.sqrt(2 * np.pi)
    return float(np.sqrt(2) * np.sqrt(0.05 * 0.95 / trials) / (2 * phi * 1.96))


def earliest(rows, trials: int) -> list[dict[str, Any]]:
    """Per scene, circuit and method: the earliest decision time at which at least DECIDED of
    the cycles are decided with a 95 % error no worse than the 5 s window mean's on the same
    scene and circuit (the paper's sorting reads at 5 s; it publishes no error in mm for it),
    within the sampling tolerance ``same_as(trials)``. ``decision_time_s`` None: not by 5 s."""
    from fluidsense.controller.sensing.decision import METHODS

    tol = same_as(trials)
    out = []
    for scene in SCENES:
        for circuit in CIRCUITS:
            mine = [r for r in rows if r["scene"] == scene and r["circuit"] == circuit]
            ref = next(r for r in mine if r["method"] == "window" and r["decision_time_s"] == 5.0)["err95_mm"]
            for m in METHODS:
                ok = [r for r in mine if r["method"] == m and r["err95_mm"] is not None
                      and r["decided_fraction"] >= DECIDED and r["err95_mm"] <= ref * (1 + tol)]
                best = min(ok, key=lambda r: r["decision_time_s"], default=None)
                out.append({"scene": scene, "circuit": circuit, "method": m, "reference_err95_mm": ref,
                            "decision_time_s": None if best is None else best["decision_time_s"],
                            "err95_mm": None if best is None else best["err95_mm"]})
    return out
