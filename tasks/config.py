"""Task files (config/tasks/*.yaml): poses, slots, pressures, windows, thresholds, and an
optional simulation scenario (what lies in which slot on a simulated cell)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated, Literal

from fluidsense.common.models import Integer, Real, StrictModel
from fluidsense.common.world import Pose, WorldObject
from fluidsense.controller.config import load_model
from fluidsense.controller.config.loading import referenced_file, shipped_candidates
from pydantic import Field, RootModel, model_validator


class Motion(StrictModel):
    speed_m_s: Real = Field(0.25, gt=0, le=1.0)
    acc_m_s2: Real = Field(1.2, gt=0, le=3.0)
    approach_m: Real = Field(0.08, ge=0, le=0.5, description="height above a slot for approach and retreat")


class _TaskBase(StrictModel):
    cell: str = Field(min_length=1, description="cell config, relative to the task file")
    motion: Motion = Motion()
    slots: dict[str, Pose] = Field(min_length=1, description="named grip poses")
    home: Pose | None = None

    def _check_slots(self, names: list[str], what: str) -> None:
        missing = [n for n in names if n not in self.slots]
        if missing:
            raise ValueError(f"{what} names slots that are not in slots: {missing}")


class SortingTask(_TaskBase):
    """Modified insertion sort into a separate sorted array by P_eq (paper: sorting)."""

    task: Literal["sorting"]
    input_slots: list[str] = Field(min_length=1)
    sorted_slots: list[str] = Field(min_length=1)
    order_mm: list[Real] | None = Field(
        None, description="simulation: diameters placed in the input slots, in order (--order overrides)")
    object_offset_mm: Real = Field(0.0, ge=0, le=50, description="simulation: objects lie this far off-centre")

    @model_validator(mode="after")
    def _consistent(self) -> SortingTask:
        self._check_slots(self.input_slots + self.sorted_slots, "input_slots/sorted_slots")
        if len(self.sorted_slots) < len(self.input_slots):
            raise ValueError("need at least as many sorted_slots as input_slots")
        if self.order_mm is not None and len(self.order_mm) > len(self.input_slots):
            raise ValueError(f"order_mm has {len(self.order_mm)} objects for {len(self.input_slots)} input slots")
        return self


class Tomato(StrictModel):
    """Simulation: a tomato on its stem."""

    diameter_mm: Real = Field(60.0, gt=0, le=200)
    stiffness_n_per_mm: Real | None = Field(6.0, gt=0, le=1e6)
    min_grip_kpa: Real = Field(0.0, ge=0, le=100, description="pressure above contact needed to pull it off")
    slip_after_s: Real | None = Field(None, gt=0, le=1e4, description="slips into the palm this long after the grip")


class PickingTask(_TaskBase):
    """Pick tomatoes, escalating the tank pressure; picked when dP > threshold (paper:
    tomato picking)."""

    task: Literal["picking"]
    tomato_slots: list[str] = Field(min_length=1)
    place_slots: list[str] = Field(min_length=1)
    p0_steps_kpa: list[Real] = Field(default_factory=lambda: [62.0, 70.0, 78.0], min_length=1, max_length=10)
    dp_threshold_kpa: Real = Field(0.2, gt=0, le=10)
    slip_drop_kpa: Real = Field(0.15, gt=0, le=10, description="a drop this large between the carried and the "
                                 "measurement window, while still touching, is a slip into the palm")
    retract_after_s: Real = Field(4.0, gt=0, le=60, description="turn and retract this long after opening")
    retract_m: Real = Field(0.09, ge=0, le=0.5)
    tomatoes: list[Tomato] | None = Field(None, description="simulation: one per tomato slot")

    @model_validator(mode="after")
    def _consistent(self) -> PickingTask:
        self._check_slots(self.tomato_slots + self.place_slots, "tomato_slots/place_slots")
        if len(self.place_slots) < len(self.tomato_slots):
            raise ValueError("need a place slot per tomato")
        if self.tomatoes is not None and len(self.tomatoes) != len(self.tomato_slots):
            raise ValueError("tomatoes needs one entry per tomato slot")
        return self


class RipenessObject(StrictModel):
    name: str = Field(min_length=1, max_length=40)
    diameter_mm: Real = Field(gt=0, le=200)
    stiffness_n_per_mm: Real | None = Field(None, gt=0, le=1e6, description="None: rigid dummy")
    relaxed_stiffness_n_per_mm: Real | None = Field(None, gt=0, le=1e6, description="after creep")
    creep_s: Real = Field(0.0, ge=0, le=1e4)
    ripe: bool | None = Field(None, description="truth (None for dummies)")


class RipenessTask(_TaskBase):
    """Calibrate on dummies, then flag the overripe tomato: D0 at contact (t_c at a dP
    threshold, t_c by first rise, or dP_max) against D1 at equilibrium (dP_eq) (paper:
    ripeness)."""

    task: Literal["ripeness"]
    dummy_slots: list[str] = Field(min_length=2)
    dummy_diameters_mm: list[Real] = Field(default_factory=lambda: [45.0, 50.0, 55.0, 60.0, 65.0])
    object_slots: list[str] = Field(min_length=1)
    objects: list[RipenessObject] = Field(min_length=1)
    rounds: Integer = Field(5, ge=1, le=100)
    grips_per_object: Integer = Field(2, ge=1, le=10)
    calibration_grips: Integer = Field(4, ge=2, le=20, description="per dummy; the first only aligns it")
    d0_from: Literal["t_c_threshold", "t_c_onset", "t_c_slope", "dp_max"] = Field(
        "t_c_threshold", description="t_c at a dP threshold (the paper's fix), t_c at the first rise of dP "
        "(the paper's first attempt), t_c by change of slope, or dP_max")
    overripe_mm: Real | None = Field(None, gt=0, description="D0 - D1 above this is overripe (default 3 mm, "
                                      "0.5 mm with dp_max as in the paper)")
    centering_grip: bool = Field(False, description="grip once before measuring to centre the object")
    misalignment_mm: Real = Field(0.0, ge=0, le=20, description="simulation: objects lie up to this off-centre")
    shuffle_seed: Integer = 0

    @model_validator(mode="after")
    def _consistent(self) -> RipenessTask:
        self._check_slots(self.dummy_slots + self.object_slots, "dummy_slots/object_slots")
        if len(self.dummy_slots) != len(self.dummy_diameters_mm):
            raise ValueError("one dummy diameter per dummy slot")
        if len(self.objects) > len(self.object_slots):
            raise ValueError("more objects than object slots")
        return self

    @property
    def threshold_mm(self) -> float:
        if self.overripe_mm is not None:
            return self.overripe_mm
        return 0.5 if self.d0_from == "dp_max" else 3.0


TaskFile = Annotated[SortingTask | PickingTask | RipenessTask, Field(discriminator="task")]


class TaskDocument(RootModel[TaskFile]):
    """A whole task file."""


def task_file(name: str | Path) -> Path:
    """The task file ``name`` names: the path as given when it exists, else the shipped task of
    that name (``sorting``, ``sorting.yaml`` or ``tasks/sorting.yaml``), so that the commands
    of the docs run from an integrator's own folder as from the checkout. Neither there: the
    path as given, which load_task then reports as unreadable."""
    given = Path(name)
    if given.exists():
        return given
    for candidate in shipped_candidates(os.fspath(name), "tasks", ".yaml"):
        if candidate.is_file():
            return candidate
    return given


def load_task(path: str | Path) -> SortingTask | PickingTask | RipenessTask:
    """Load a task file; errors name the file and the field."""
    return load_model(TaskDocument, path).root


def cell_path(task_path: str | Path, task) -> Path:
    """The cell config the task file names (relative to it); it must exist."""
    return referenced_file(Path(task_path).parent / task.cell, task_path, "cell").resolve()


__all__ = ["Motion", "PickingTask", "RipenessTask", "SortingTask", "TaskFile", "Tomato", "WorldObject",
           "cell_path", "load_task", "task_file"]
