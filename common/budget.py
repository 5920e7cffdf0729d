"""The error budget of a rig's parts: what the simulated cell draws once per session and
once per cycle beyond the noise its sensor models already have.

Every field is a half-width of a rectangular distribution (a datasheet bound with nothing
known inside it; GUM, JCGM 100:2008, 4.3.7: sd = half-width / sqrt(3)). The figures and
their sources are tabulated in ``fluidsense.simulator.parts``; a profile copies the ones
its parts carry. All default to 0: a profile without a ``budget`` block behaves as before.

What is drawn when (docs/physics.md, "Error budget"):

- per session (a fresh cell: the rig set up again): the actuator sensor's zero within
  its total error band, the regulator's setpoint error, the flow controller's accuracy
  of rate;
- per target (placed by hand): the placement error of the target;
- per cycle: the flow sensor's repeatability of reading (the sensors' per-sample noise
  and the regulator's and flow controller's repeatability are the existing fields of
  their models).
"""

from __future__ import annotations

import math

from fluidsense.common.models import Real, StrictModel
from pydantic import Field


class PartsBudget(StrictModel):
    sensor_zero_kpa: Real = Field(
        0.0, ge=0, le=100, description="actuator sensor zero, per session, within its total error band; the "
        "per-cycle offset (sequence.offset_s) removes it, so it reaches no method that reads one")
    regulator_setpoint_kpa: Real = Field(
        0.0, ge=0, le=100, description="regulator output error for one setpoint, per session")
    flow_controller_of_rate: Real = Field(
        0.0, ge=0, le=0.5, description="mass flow controller's delivered flow error, fraction of rate, per session")
    flow_sensor_of_reading: Real = Field(
        0.0, ge=0, le=0.5, description="flow sensor's repeatability, fraction of reading, per cycle")
    placement_mm: Real = Field(
        0.0, ge=0, le=50, description="hand placement of a target (caliper), per placement")

    def session_rel_sd(self, setpoint_kpa: float | None, flow_driven: bool) -> float:
        """The sd, as a fraction of the feature, that a rig set up again adds to every reading.

        The per-session parts act on the drive: the regulator's setpoint error on a cycle
        driven by a regulated pressure (``setpoint_kpa``, gauge), the flow controller's
        accuracy of rate on one driven by a set flow. To first order every feature (a
        settled pressure, a delivered volume, a time to contact) scales with its drive, so
        the drive's relative error is the feature's; on the static plant the elasticity is
        0.85-1.15 for the three distance methods (tests/unit/test_budget.py). Rectangular
        half-widths, sd = half-width / sqrt(3) (GUM 4.3.7)."""
        rel = 0.0
        if setpoint_kpa:
            rel = math.hypot(rel, self.regulator_setpoint_kpa / abs(setpoint_kpa) / math.sqrt(3))
        if flow_driven:
            rel = math.hypot(rel, self.flow_controller_of_rate / math.sqrt(3))
        return rel
