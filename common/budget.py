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
