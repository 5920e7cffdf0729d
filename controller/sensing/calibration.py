"""Calibration curves: fit a feature against a known target, invert it with an interval.

The curve is fitted as the paper draws it, feature against target (P_eq against h), by
least squares (numpy's polynomial fit), one point per cycle. Sensing inverts it: the
estimate is the target whose predicted feature equals the measurement, and the interval
is the classical inverse-prediction interval: the repeatability of one cycle (pure
error: window noise, offset noise, cycle-to-cycle variation; it shrinks with averaging),
the curve's lack of fit (it does not) and the uncertainty of the curve itself, divided by
the local slope (``fitstats``). ``estimate`` also says when there is no object (the
feature reads what the actuator reads with nothing there, ``free_y``) or when the object
is outside the calibrated range.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from fluidsense.common.errors import ConfigError, FluidsenseError
from fluidsense.common.files import (
    MB,
    check_name,
    decode_utf8,
    nested_within,
    read_bounded,
)
from fluidsense.common.models import FieldError, Integer, Real, StrictModel
from fluidsense.common.names import FEATURES, FIT_DEGREE, NEEDS_REFERENCE  # noqa: F401 - their home is light
from fluidsense.controller.config.loading import validate
from pydantic import Field, JsonValue, model_validator

from .estimate import Estimate, quantity_name, si_unit
from .fitstats import fit_stats, load_quantiles, prediction_sd, t_quantile

FORMAT = "fluidsense-calibration/1"



class CalibrationError(FluidsenseError, ValueError):
    """A calibration cannot be fitted or inverted."""


def feature_value(result, feature: str) -> float | None:
    """The named feature of a cycle result, in its edge unit (None if not available)."""
    attr, _, scale = FEATURES[feature]
    v = getattr(result, attr)
    return None if v is None or not math.isfinite(v) else v * scale


# a reading within this many sd of the free (nothing there) level, or beyond it, is "no
# object": one-sided, 1 in 740 readings of an empty actuator would claim an object
NO_OBJECT_Z = 3.0


@dataclass
class Inversion:
    """The target for a feature value, in the calibration's units (the curve read
    backwards; ``estimate`` adds what the reading means)."""

    estimate: float
    interval95: tuple[float, float]
    unit: str
    feature: str
    measured: float
    extrapolated: bool
    half_width: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["interval95"] = list(self.interval95)
        return d


@dataclass
class Calibration:
    """A fitted calibration with its metadata; saved as JSON."""

    profile: str
    method: str
    feature: str
    feature_unit: str
    scene: dict[str, Any]
    target: str
    target_unit: str
    fit: str
    coeffs: list[float]  # highest power first (numpy.polyfit)
    x: list[float]  # target of every calibration cycle
    y: list[float]  # feature of every calibration cycle
    window: dict[str, Any] = field(default_factory=dict)
    date: str = ""
    seed: int | None = None
    cycles: int = 0
    drop_first: int = 0
    residual_sd: float = 0.0
    r2: float = 0.0
    free_y: list[float] = field(default_factory=list)  # the feature with nothing there, one per cycle
    # sd of a reading from a rig set up again, as a fraction of the feature (the profile's
    # parts budget: PartsBudget.session_rel_sd); 0 for a curve used in its own session
    session_rel_sd: float = 0.0
    format: str = FORMAT

    # ------------------------------------------------------------------ fit
    @classmethod
    def fit_points(cls, x, y, fit: str = "linear", **meta) -> Calibration:
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        deg = FIT_DEGREE[fit]
        if len(np.unique(x)) <= deg:
            raise CalibrationError(f"a {fit} fit needs at least {deg + 1} distinct targets, got {len(np.unique(x))}")
        if len(x) <= deg + 1:
            raise CalibrationError(f"a {fit} fit needs more than {deg + 1} points to estimate its residual")
        coeffs = np.polyfit(x, y, deg)
        resid = y - np.polyval(coeffs, x)
        dof = len(x) - (deg + 1)
        sd = float(np.sqrt(np.sum(resid**2) / dof))
        ss_tot = float(np.sum((y - y.mean()) ** 2))
        r2 = 1.0 - float(np.sum(resid**2)) / ss_tot if ss_tot > 0 else 0.0
        return cls(fit=fit, coeffs=[float(c) for c in coeffs], x=x.tolist(), y=y.tolist(), residual_sd=sd,
                   r2=r2, date=meta.pop("date", _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")),
                   **meta)

    @property
    def slope(self) -> float:
        """Mean feature change per unit of target over the calibrated range."""
        lo, hi = min(self.x), max(self.x)
        return float((np.polyval(self.coeffs, hi) - np.polyval(self.coeffs, lo)) / (hi - lo))

    def predict(self, x) -> np.ndarray:
        return np.polyval(self.coeffs, x)

    # -------------------------------------------------------------- invert
    def _crossing(self, measured: float) -> float | None:
        """The target whose predicted feature is ``measured`` (searched half a range
        beyond each end, the root nearest the range preferred); None if there is none."""
        lo, hi = min(self.x), max(self.x)
        span = hi - lo
        grid = np.linspace(lo - 0.5 * span, hi + 0.5 * span, 2001)
        g = self.predict(grid) - measured
        crossings = np.nonzero(np.sign(g[:-1]) != np.sign(g[1:]))[0]
        if len(crossings) == 0:
            return None
        mid = 0.5 * (lo + hi)
        k = min(crossings, key=lambda i: abs(grid[i] - mid))
        # the curve is a polynomial: its root in that grid cell, from all of its roots
        roots = np.roots(np.subtract(self.coeffs, [0.0] * (len(self.coeffs) - 1) + [measured]))
        real = roots.real[np.abs(roots.imag) <= 1e-9 * (1.0 + np.abs(roots.real))]
        a, b = grid[k], grid[k + 1]
        return float(min(real, key=lambda r: max(a - r, r - b, 0.0)))

    def _between_setups_sd(self, y: float) -> float:
        """sd of a reading ``y`` (calibration units) from a later set-up against the
        calibration's: two set-ups' draws (the calibration's own is a bias every later
        reading inherits), which no number of averaged cycles removes."""
        return math.sqrt(2) * self.session_rel_sd * y

    def invert(self, measured: float, n_measurements: int = 1, coverage: float = 0.95) -> Inversion:
        """Target for a measured feature (the mean of ``n_measurements`` cycles, edge
        units), with its interval (``coverage``, 95 % by default)."""
        est = self._crossing(measured)
        lo, hi = min(self.x), max(self.x)
        if est is None:
            span = hi - lo
            raise CalibrationError(
                f"measured {self.feature} {measured:.4g} {self.feature_unit} is outside what the calibration "
                f"predicts for {self.target} in [{lo - 0.5 * span:.3g}, {hi + 0.5 * span:.3g}] {self.target_unit}")
        slope = float(np.polyval(np.polyder(self.coeffs), est))
        if slope == 0:
            raise CalibrationError(f"the calibration is flat at {self.target} = {est:.3g}: no resolution there")
        fs = fit_stats(self.x, self.y, self.coeffs)
        sd = math.hypot(prediction_sd(fs, est, n_measurements), self._between_setups_sd(measured))
        half = t_quantile(coverage, fs.dof) * sd / abs(slope)
        return Inversion(est, (est - half, est + half), self.target_unit, self.feature, measured,
                         extrapolated=not lo <= est <= hi, half_width=half)

    def estimate(self, feature_value: float | None, n_measurements: int = 1, coverage: float = 0.95) -> Estimate:
        """What a measured feature (SI: Pa, s, m^3; the mean of ``n_measurements``
        cycles; None when the cycle gave none, e.g. no contact) says about the target."""
        unit, factor = si_unit(self.target_unit)
        scale = FEATURES[self.feature][2]
        base = {"quantity": quantity_name(self.target, self.target_unit), "coverage": coverage, "unit": unit,
                "feature": self.feature, "measured": feature_value, "n_measurements": max(n_measurements, 1)}
        if feature_value is None or not math.isfinite(feature_value):
            return Estimate(status="no_object", detail=f"no {self.feature}: no contact detected", **base)
        y = feature_value * scale
        free = self.free_reading(y, n_measurements)
        if free is not None:
            return Estimate(status="no_object", detail=free, **base)
        lo, hi = min(self.x), max(self.x)
        est = self._crossing(y)
        if est is None:
            above = (y - float(self.predict(0.5 * (lo + hi)))) * self.slope > 0
            return self._out_of_range(base, hi if above else lo, above, factor,
                                      f"{self.feature} {y:.4g} {self.feature_unit} is beyond what the curve reaches")
        inv = self.invert(y, n_measurements, coverage)
        a, b = inv.interval95
        # a size beyond the calibrated targets would be an extrapolation, and at the range's
        # edge that faces the free level (the smallest object a gripper closes on) an empty
        # gripper reads about what that object does: only the bound is said there
        if not lo <= inv.estimate <= hi:
            above = inv.estimate > hi
            return self._out_of_range(base, hi if above else lo, above, factor,
                                      f"the reading points to {inv.estimate:.3g} {self.target_unit}, outside the "
                                      f"calibrated {lo:g} .. {hi:g} {self.target_unit}")
        return Estimate(status="ok", value=inv.estimate * factor, lo=a * factor, hi=b * factor, **base)

    @staticmethod
    def _out_of_range(base: dict[str, Any], bound: float, above: bool, factor: float, detail: str) -> Estimate:
        b = bound * factor
        return Estimate(status="out_of_range", bound=b, lo=b if above else None, hi=None if above else b,
                        detail=detail, **base)

    def free_reading(self, y: float, n_measurements: int) -> str | None:
        """Why ``y`` is what the actuator reads with nothing there, or None. A reading
        counts as free when it is within NO_OBJECT_Z sd of the free level or beyond it
        (on the side away from the calibrated range)."""
        if not self.free_y:
            return None
        free = np.asarray(self.free_y, dtype=float)
        sd1 = float(np.std(free, ddof=1)) if len(free) > 2 else fit_stats(self.x, self.y, self.coeffs).pure_sd
        level = float(np.mean(free))
        # a later set-up moves the free level as it moves every reading (invert): without
        # it, an empty flow-controlled actuator read as an object in 12 % of fresh sessions
        sd = math.hypot(sd1 * math.sqrt(1.0 / max(n_measurements, 1) + 1.0 / len(free)),
                        self._between_setups_sd(level))
        toward = np.sign(float(np.mean(self.predict([min(self.x), max(self.x)]))) - level)
        if (y - level) * toward < NO_OBJECT_Z * sd:
            return (f"{self.feature} {y:.4g} {self.feature_unit} is within the noise of the free reading "
                    f"{level:.4g} +- {NO_OBJECT_Z * sd:.2g} {self.feature_unit}")
        return None

    # --------------------------------------------------------------- files
    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        """A calibration file, checked as untrusted input: a regular file of at most
        ``MAX_FILE_BYTES``, UTF-8 JSON without NaN or infinity, every field of the right
        type, the curve consistent with its points. Errors: ``FILE: field: reason``."""
        path = check_name(path)
        text = decode_utf8(read_bounded(path, MAX_FILE_BYTES, "a calibration file"), path)
        try:
            data = json.loads(text, parse_constant=_refuse_constant)
        except json.JSONDecodeError as exc:
            raise ConfigError(f"{path}:{exc.lineno}:{exc.colno}: not a calibration file: JSON: {exc.msg}") from exc
        except ValueError as exc:  # NaN, Infinity
            raise ConfigError(f"{path}: not a calibration file: {exc}") from exc
        except RecursionError as exc:
            raise ConfigError(f"{path}: not a calibration file: JSON nested too deeply") from exc
        if not nested_within(data, MAX_DEPTH):
            raise ConfigError(f"{path}: not a calibration file: JSON nested more than {MAX_DEPTH} levels deep")
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise ConfigError(f"{path}: format: not a calibration file (format is not {FORMAT!r})")
        calibration = cls(**validate(CalibrationFile, data, path).model_dump())
        load_quantiles()  # its intervals need scipy.special: imported now, not in a sample loop
        return calibration


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number a calibration can hold")


# The largest calibration the profile's plan allows (200 targets x 1000 cycles, two
# numbers a point) is about 10 MB of indented JSON; the shipped protocols write a few KB.
MAX_FILE_BYTES = 16 * MB
MAX_POINTS = 200 * 1000
MAX_DEPTH = 16  # the scene and window objects are flat
JsonObject = Annotated[dict[str, JsonValue], Field(max_length=100)]


class CalibrationFile(StrictModel):
    """What a calibration file must hold (what ``Calibration.save`` writes)."""

    format: Literal["fluidsense-calibration/1"]
    profile: str = Field(min_length=1, max_length=80, pattern=r"^[^\x00-\x1f]+$",
                         description="the profile's name (sense looks it up in config/profiles/)")
    method: str = Field(max_length=40)
    feature: Literal[tuple(FEATURES)]  # type: ignore[valid-type]
    feature_unit: str = Field(max_length=20)
    scene: JsonObject
    target: str = Field(min_length=1, max_length=80)
    target_unit: str = Field(max_length=20)
    fit: Literal[tuple(FIT_DEGREE)]  # type: ignore[valid-type]
    coeffs: list[Real] = Field(min_length=2, max_length=4)
    x: list[Real] = Field(max_length=MAX_POINTS)
    y: list[Real] = Field(max_length=MAX_POINTS)
    window: JsonObject = Field(default_factory=dict)
    date: str = Field("", max_length=64)
    seed: Integer | None = None
    cycles: Integer = Field(0, ge=0)
    drop_first: Integer = Field(0, ge=0)
    residual_sd: Real = Field(0.0, ge=0)
    r2: Real = 0.0
    free_y: list[Real] = Field(default_factory=list, max_length=MAX_POINTS,
                               description="the feature with nothing there (one per cycle): 'no object' readings")
    session_rel_sd: Real = Field(0.0, ge=0, le=1, description="sd of a reading from a rig set up again, a "
                                 "fraction of the feature; absent in files written before it: 0")

    @model_validator(mode="after")
    def _consistent(self) -> CalibrationFile:
        deg = FIT_DEGREE[self.fit]
        if len(self.coeffs) != deg + 1:
            raise FieldError("coeffs", f"a {self.fit} fit has {deg + 1} coefficients, got {len(self.coeffs)}")
        if len(self.x) != len(self.y):
            raise FieldError("y", f"{len(self.y)} features for {len(self.x)} targets")
        if len(set(self.x)) <= deg or len(self.x) <= deg + 1:
            raise FieldError("x", f"a {self.fit} fit needs more than {deg + 1} points over at least {deg + 1} "
                             f"distinct targets, got {len(self.x)} over {len(set(self.x))}")
        return self
