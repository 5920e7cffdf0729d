"""A simulated work cell's contents: named slots at poses, and the objects in them.

Plain data, like the scenes: a task file carries one as its simulation scenario, and the
simulated cell turns it into gripping, carrying and placing (simulator/world.py).
Poses are UR's [x, y, z, rx, ry, rz] in metres and radians.
"""

from __future__ import annotations

from typing import Annotated

from fluidsense.common.models import Real, StrictModel
from pydantic import Field, model_validator

Pose = Annotated[tuple[Real, Real, Real, Real, Real, Real], Field(description="x, y, z (m), rx, ry, rz (rad)")]


class WorldObject(StrictModel):
    """Something the gripper can take: a cylinder, a dummy, a tomato."""

    name: str = Field(min_length=1, max_length=40)
    diameter_mm: Real = Field(gt=0, le=500)
    stiffness_n_per_mm: Real | None = Field(None, gt=0, le=1e6, description="None: rigid")
    relaxed_stiffness_n_per_mm: Real | None = Field(None, gt=0, le=1e6, description="viscoelastic: after creep")
    creep_s: Real = Field(0.0, ge=0, le=1e4, description="creep time constant (0: purely elastic)")
    offset_mm: Real = Field(0.0, ge=0, le=100, description="off-centre in its slot; a grip centres it")
    min_grip_kpa: Real = Field(
        0.0, ge=0, le=100, description="pressure above the contact pressure needed to hold it when the arm moves "
        "away (its weight and grip; 0: any contact holds it)")
    slip_after_s: Real | None = Field(
        None, gt=0, le=1e4, description="slips into the palm this long after the grip closes")
    slip_diameter_mm: Real = Field(
        28.0, gt=0, le=500, description="after a slip it sits in the palm: the fingers close on it as on a "
        "cylinder this wide (28 mm gives the paper's dP of about 0.1 kPa with the sorting gripper at 62 kPa)")
    ripe: bool | None = Field(None, description="ground truth for ripeness tasks")


class WorldSlot(StrictModel):
    name: str = Field(min_length=1, max_length=40)
    pose: Pose
    object: str | None = None


class WorldSpec(StrictModel):
    slots: list[WorldSlot] = Field(min_length=1, max_length=200)
    objects: list[WorldObject] = Field(default_factory=list, max_length=200)
    reach_mm: Real = Field(15.0, gt=0, le=500, description="the tool is at a slot when this close to its pose")

    @model_validator(mode="after")
    def _consistent(self) -> WorldSpec:
        names = [o.name for o in self.objects]
        if len(set(names)) != len(names):
            raise ValueError(f"object names must be unique, got {names}")
        slots = [s.name for s in self.slots]
        if len(set(slots)) != len(slots):
            raise ValueError(f"slot names must be unique, got {slots}")
        placed = [s.object for s in self.slots if s.object is not None]
        unknown = set(placed) - set(names)
        if unknown:
            raise ValueError(f"slots hold unknown objects {sorted(unknown)}")
        if len(set(placed)) != len(placed):
            raise ValueError("an object can be in one slot only")
        return self
