"""The ``gripper:`` section of a cell config: what the gripper commands (``grip``,
``release``, ``measure``) load and how they supervise a held object.

Calibration files are named relative to the cell config (like ``profile``), or by the
name of a shipped one (``pneunet-gripper-p_eq``: loading.named_file says the order), and
are read and checked when the config is loaded, so that a missing or foreign calibration stops the
daemon before anything starts (``FILE: gripper.calibrations.N: reason``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fluidsense.common.errors import ConfigError
from fluidsense.common.models import Real, StrictModel
from pydantic import Field

from .loading import named_file, referenced_file

MAX_CALIBRATIONS = 8


class GripperConfig(StrictModel):
    calibrations: list[str] = Field(default_factory=list, max_length=MAX_CALIBRATIONS,
                                    description="calibration files (fluidsense calibrate) for this cell's profile, "
                                                "one per feature; relative to the cell config, else a shipped "
                                                "calibration's name")
    max_hold_s: Real = Field(600.0, gt=0, le=7 * 86400,
                             description="a grip held this long (sample time) is released: the gripper vents")
    slip_drop_kpa: Real = Field(0.3, gt=0, le=100,
                                description="an abrupt fall of the held pressure by this much is a slip")
    slip_within_s: Real = Field(0.5, ge=0.05, le=10,
                                description="a fall by slip_drop_kpa within this long is a slip (slower: a leak)")
    settle_s: Real = Field(2.0, ge=0, le=60,
                           description="virtual time: sample time run after a scene change while holding, so "
                                       "that the grip sees it (in real time samples flow anyway)")


def resolve_calibrations(data: dict[str, Any], path: Path) -> dict[str, Any]:
    """The cell config's data with its calibration files found: next to the file, else
    shipped (a missing one is ``FILE: gripper.calibrations.N: ...``)."""
    section = data.get("gripper")
    if not isinstance(section, dict) or not isinstance(section.get("calibrations"), list):
        return data  # absent, or the validation says what is wrong with it
    names = [str(named_file(c, path, f"gripper.calibrations.{i}", "calibrations", ".json"))
             if isinstance(c, str) else c for i, c in enumerate(section["calibrations"])]
    return {**data, "gripper": {**section, "calibrations": names}}


def check_calibrations(cfg: GripperConfig, profile: str, path: Path) -> None:
    """Every calibration named must load and be one of this profile's, its target a length."""
    from fluidsense.controller.requests.estimates import (
        load_calibration,  # the sensing code loads only if named
    )

    for i, name in enumerate(cfg.calibrations):
        field = f"gripper.calibrations.{i}"
        load_calibration(referenced_file(name, path, field), profile, f"{path}: {field}")


__all__ = ["GripperConfig", "check_calibrations", "resolve_calibrations", "ConfigError"]
