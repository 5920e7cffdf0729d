"""Calibrated estimates for the gripper's events: the one place that turns a calibration
and a measured feature into the agreed estimate shape

    {"quantity": str, "value": float | None, "lo": float | None, "hi": float | None,
     "coverage": float, "status": "ok" | "no_object" | "out_of_range"}

(SI inside: metres), and that shape into what the events publish (mm).

``estimate()`` is a thin adapter over today's ``Calibration.invert``: a calibration that
offers ``estimate(feature_value)`` itself (with its own "no object" and range decisions)
is used as it is, so this module is where that swap happens and nothing else changes.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from common.errors import ConfigError
from common.names import FEATURES
from controller.sensing.calibration import Calibration, CalibrationError

COVERAGE = 0.95  # Calibration.invert's interval
MM = 1e-3
ESTIMATE_STATUS = ("ok", "no_object", "out_of_range")


def quantity_of(cal: Calibration) -> str:
    """``diameter_mm`` -> ``diameter``: the quantity, its unit said by the published name."""
    return cal.target.removesuffix(f"_{cal.target_unit}")


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


def estimate(cal: Calibration, feature_value: float) -> dict[str, Any]:
    """The agreed estimate shape (SI) for a measured feature in the calibration's unit."""
    own = getattr(cal, "estimate", None)
    if callable(own):  # the calibration decides by itself (sensing issue 16)
        return dict(own(feature_value))
    base = {"quantity": quantity_of(cal), "coverage": COVERAGE}
    try:
        est = cal.invert(feature_value)
    except CalibrationError:
        return {**base, "value": None, "lo": None, "hi": None, "status": "out_of_range"}
    lo, hi = est.interval95
    return {**base, "value": est.estimate * MM, "lo": lo * MM, "hi": hi * MM,
            "status": "out_of_range" if est.extrapolated else "ok"}


def of_result(cals: list[Calibration], result: Any) -> list[dict[str, Any]]:
    """One estimate per calibration whose feature the cycle result has, with its feature."""
    out = []
    for cal in cals:
        attr, _, scale = FEATURES[cal.feature]
        value = getattr(result, attr, None)
        if value is not None:
            out.append({**estimate(cal, value * scale), "feature": cal.feature})
    return out


def no_object(est: dict[str, Any]) -> dict[str, Any]:
    """The estimate when the grip touched nothing (told by the free-air reference)."""
    return {**est, "value": None, "lo": None, "hi": None, "status": "no_object"}


def to_edge(est: dict[str, Any]) -> dict[str, Any]:
    """SI estimate -> the published one (mm, the unit in the names)."""
    mm = {k: None if est.get(k) is None else est[k] / MM for k in ("value", "lo", "hi")}
    return {"quantity": est["quantity"], "value_mm": mm["value"], "lo_mm": mm["lo"], "hi_mm": mm["hi"],
            "coverage": est["coverage"], "status": est["status"], "feature": est.get("feature")}
