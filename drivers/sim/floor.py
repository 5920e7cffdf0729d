"""The simulated plant's noise-free step responses, for a study that needs its circuit's
physical floor beside its cycles (tasks/speed_accuracy.py): when an object is reached and
when the pressure has settled. The simulator stays behind the sim driver (the layering's
rule: only this package imports it)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from fluidsense.common.hardware import Hardware
from fluidsense.simulator.timing import settled_time, step_response


def step_floor(hw: Hardware, scenes: Sequence[Any], p0_kpa: float, band_kpa: float,
               t_end_s: float) -> list[tuple[float | None, float]]:
    """Per scene: (when the actuator first reaches the object, None when it never does
    within ``t_end_s``; the last time the pressure is more than ``band_kpa`` from its value
    at ``t_end_s``), for the tank at ``p0_kpa`` opened onto the actuator at t = 0."""
    out = []
    for scene in scenes:
        resp = step_response(hw, scene, p0_kpa, t_end_s)
        out.append((resp.t_contact_s, settled_time(resp, band_kpa)))
    return out
