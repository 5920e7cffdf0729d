"""Calibrated estimates for the gripper's events: a calibration and a cycle's features
into the estimate shape the events carry (``controller.sensing.estimate.Estimate``: SI
inside, metres), and that shape into what the events publish (mm).

The calibration decides "ok", "no object" (the reading is the calibration's free level)
and "out of range" itself; the gripper adds "no object" when the grip's dP against the
free-air reference shows no contact.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fluidsense.common.errors import ConfigError
from fluidsense.common.names import FEATURES
from fluidsense.controller.sensing.calibration import Calibration

MM = 1e-3


def load_calibration(path: str | Path, profile: str, where: str) -> Calibration:
    """A calibration the gripper can use on ``profile``; ConfigError (``where: reason``)
    for one that is not (its own file errors name that file)."""
    cal = Calibration.load(path)
    if cal.profile != profile:
        raise ConfigError(f"{where}: {path} calibrates profile {cal.profile!r}, this cell runs {profile!r}")
    if cal.target_unit != "mm":
        raise ConfigError(f"{where}: {path} estimates {cal.target} in {cal.target_unit!r}: the gripper reports "
                          "sizes and distances in mm")
    return cal


def of_result(cals: list[Calibration], result: Any) -> list[dict[str, Any]]:
    """One estimate per calibration whose feature the cycle result has, with its feature."""
    out = []
    for cal in cals:
        attr = FEATURES[cal.feature][0]
        value = getattr(result, attr, None)  # SI; None when the cycle gave none (no contact)
        out.append({**cal.estimate(value).as_dict(), "feature": cal.feature})
    return out


def no_object(est: dict[str, Any]) -> dict[str, Any]:
    """The estimate when the grip touched nothing (told by the free-air reference)."""
    return {**est, "value": None, "lo": None, "hi": None, "status": "no_object"}


def to_edge(est: dict[str, Any]) -> dict[str, Any]:
    """SI estimate -> the published one (mm, the unit in the names)."""
    mm = {k: None if est.get(k) is None else est[k] / MM for k in ("value", "lo", "hi")}
    return {"quantity": est["quantity"], "value_mm": mm["value"], "lo_mm": mm["lo"], "hi_mm": mm["hi"],
            "coverage": est["coverage"], "status": est["status"], "feature": est.get("feature")}
