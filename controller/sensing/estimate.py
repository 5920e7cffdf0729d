"""What a calibrated measurement says: a value with an interval, or that there is nothing
to measure ("no_object") or nothing the calibration can say ("out_of_range").

Inside, everything is SI (m, rad, Pa); ``to_edge()`` gives the calibration's own units
(mm, deg, kPa) for the command line and JSON output.

The shape is shared with the live sensing events: ``{"quantity", "value", "lo", "hi",
"coverage", "status"}`` plus what explains it (``unit``, ``bound``, ``detail``...).
"""

from __future__ import annotations

import math
from typing import Any, Literal

from fluidsense.common.models import StrictModel
from pydantic import Field

Status = Literal["ok", "no_object", "out_of_range"]

# edge unit -> (SI unit, factor from the edge unit to SI)
_SI: dict[str, tuple[str, float]] = {
    "mm": ("m", 1e-3),
    "deg": ("rad", math.pi / 180.0),
    "kPa": ("Pa", 1e3),
    "ml": ("m^3", 1e-6),
    "s": ("s", 1.0),
    "": ("", 1.0),
}


def si_unit(edge_unit: str) -> tuple[str, float]:
    """(SI unit, factor edge -> SI) for a calibration's target unit."""
    return _SI.get(edge_unit, (edge_unit, 1.0))


def quantity_name(target: str, edge_unit: str) -> str:
    """``height_mm`` -> ``height``: the quantity without the unit its field carries."""
    suffix = "_" + edge_unit.lower()
    return target[: -len(suffix)] if edge_unit and target.lower().endswith(suffix) else target


class Estimate(StrictModel):
    """One calibrated estimate.

    ``ok``: ``value`` with the interval [lo, hi] that covers the truth with probability
    ``coverage``. ``no_object``: the feature is what the actuator reads with nothing
    there (within its noise), value/lo/hi are None. ``out_of_range``: something is there,
    beyond the calibrated range: ``bound`` is the nearest calibrated bound and the
    interval is one-sided (lo = bound when above, hi = bound when below)."""

    quantity: str = Field(min_length=1, max_length=80)
    value: float | None = None
    lo: float | None = None
    hi: float | None = None
    coverage: float = Field(0.95, gt=0, lt=1)
    status: Status = "ok"
    unit: str = Field("", max_length=20, description="SI unit of value, lo, hi and bound")
    bound: float | None = Field(None, description="out_of_range: the nearest calibrated bound")
    feature: str = Field("", max_length=40)
    measured: float | None = Field(None, description="the feature, SI (Pa, s, m^3)")
    n_measurements: int = Field(1, ge=1)
    detail: str = Field("", max_length=400, description="why, in words")

    def as_dict(self) -> dict[str, Any]:
        """The agreed event shape (SI)."""
        return self.model_dump()

    def to_edge(self, edge_unit: str, feature_scale: float = 1.0) -> dict[str, Any]:
        """The same in the calibration's units (``value_mm``...), for people and JSON files."""
        _, factor = si_unit(edge_unit)
        suffix = f"_{edge_unit.lower()}" if edge_unit else ""

        def edge(v: float | None) -> float | None:
            return None if v is None else v / factor

        return {"quantity": self.quantity, "status": self.status, "coverage": self.coverage,
                f"value{suffix}": edge(self.value), f"lo{suffix}": edge(self.lo), f"hi{suffix}": edge(self.hi),
                f"bound{suffix}": edge(self.bound), "feature": self.feature,
                "measured": None if self.measured is None else self.measured * feature_scale,
                "n_measurements": self.n_measurements, "detail": self.detail}

    def words(self, edge_unit: str, digits: int = 2) -> str:
        """One line for a person."""
        _, factor = si_unit(edge_unit)
        pct = f"{100 * self.coverage:g} %"

        def f(v: float) -> str:
            return f"{v / factor:.{digits}f}"

        if self.status == "no_object":
            return f"no object: {self.detail}" if self.detail else "no object"
        if self.status == "out_of_range":
            side = "above" if self.lo is not None else "below"
            return (f"{self.quantity} out of the calibrated range: {side} {f(self.bound)} {edge_unit}"
                    + (f" ({self.detail})" if self.detail else ""))
        return (f"{self.quantity} = {f(self.value)} {edge_unit}  ({pct} interval {f(self.lo)} .. "
                f"{f(self.hi)} {edge_unit})")
