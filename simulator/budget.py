"""The parts' error budget drawn as the real parts behave (common/budget.py): once per
session what a rig set up again changes, once per placement the target's position, once
per cycle the flow sensor's repeatability. Each figure is the half-width of a rectangular
distribution (GUM 4.3.7)."""

from __future__ import annotations

import logging

import numpy as np
from fluidsense.common.budget import PartsBudget
from fluidsense.common.scenes import PlateScene
from fluidsense.common.units import KPA

log = logging.getLogger(__name__)


def _uniform(rng: np.random.Generator, half_width: float) -> float:
    return float(rng.uniform(-half_width, half_width)) if half_width > 0 else 0.0


class SessionDraws:
    """One session's draws; its own random stream, so a profile without a budget draws
    nothing and every other stream of the cell is as before."""

    def __init__(self, budget: PartsBudget, rng: np.random.Generator):
        self.budget = budget
        self.rng = rng
        self.sensor_zero_pa = _uniform(rng, budget.sensor_zero_kpa * KPA)
        self.regulator_error_pa = _uniform(rng, budget.regulator_setpoint_kpa * KPA)
        self.flow_controller_gain = 1.0 + _uniform(rng, budget.flow_controller_of_rate)
        if budget != PartsBudget():
            log.info("session draws: sensor zero %+.3f kPa, regulator %+.3f kPa, flow controller x%.4f",
                     self.sensor_zero_pa / KPA, self.regulator_error_pa / KPA, self.flow_controller_gain)

    def flow_sensor_gain(self) -> float:
        """A new cycle's flow sensor gain (repeatability of reading)."""
        return 1.0 + _uniform(self.rng, self.budget.flow_sensor_of_reading)

    def place(self, scene):
        """The scene as a hand places it: a plate lands within the placement error of the
        height set on the caliper (never below the actuator's rest position). The
        experimenter's record, the nominal height, stays the truth a study compares with."""
        if isinstance(scene, PlateScene) and self.budget.placement_mm > 0:
            h = max(scene.height_mm + _uniform(self.rng, self.budget.placement_mm), 0.0)
            return scene.model_copy(update={"height_mm": h})
        return scene
