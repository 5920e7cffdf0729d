"""What is in front of the actuator (simulated cells only).

Plain data: the simulated plant turns a scene into a contact law for the actuator it
has. Each scene holds no more than its measurement needs. ``TARGETS`` says, per scene,
which field is the sensing target (what calibration varies and sensing estimates).
"""

from __future__ import annotations

from typing import Annotated, Literal

from fluidsense.common.models import Real, StrictModel
from pydantic import Field, model_validator

# Shore hardness -> modulus at 100 % strain (kPa): Smooth-On Ecoflex data sheets; OOO-34
# estimated from OOO-35 (17 kPa) as in the paper's Table 1 caption.
SILICONE_MODULUS_KPA = {"OO-50": 82.7, "OO-30": 69.0, "OO-10": 55.0, "OOO-34": 17.0}


class EmptyScene(StrictModel):
    """Nothing to touch: free actuation (the reference)."""

    kind: Literal["none"] = "none"


class CylinderScene(StrictModel):
    """A cylinder of diameter D between a gripper's fingers (or around which a bending
    actuator wraps). ``offset_mm`` puts it off-centre; ``stiffness_n_per_mm`` makes it
    soft (None: rigid). A viscoelastic object (a tomato) yields over time: its stiffness
    relaxes from ``stiffness_n_per_mm`` towards ``relaxed_stiffness_n_per_mm`` with time
    constant ``creep_s`` from the moment the grip closes."""

    kind: Literal["cylinder"] = "cylinder"
    diameter_mm: Real = Field(gt=0, le=500)
    offset_mm: Real = Field(0.0, ge=0, le=100)
    stiffness_n_per_mm: Real | None = Field(None, gt=0, le=1e6)
    relaxed_stiffness_n_per_mm: Real | None = Field(None, gt=0, le=1e6)
    creep_s: Real = Field(0.0, ge=0, le=1e4)

    @model_validator(mode="after")
    def _creep_needs_stiffness(self) -> CylinderScene:
        if self.relaxed_stiffness_n_per_mm is not None and self.stiffness_n_per_mm is None:
            raise ValueError("relaxed_stiffness_n_per_mm needs stiffness_n_per_mm")
        return self

    @property
    def creeps(self) -> bool:
        return self.relaxed_stiffness_n_per_mm is not None and self.creep_s > 0

    def stiffness_at(self, t_since_set_s: float) -> float | None:
        """Stiffness (N/mm) at a time after the grip closed."""
        if not self.creeps:
            return self.stiffness_n_per_mm
        import math

        k0, k1 = self.stiffness_n_per_mm, self.relaxed_stiffness_n_per_mm
        return k1 + (k0 - k1) * math.exp(-max(t_since_set_s, 0.0) / self.creep_s)


class RectangleScene(StrictModel):
    """A rectangular block gripped across: one finger pair meets the length, the other the
    width (paper, Fig. 2d-e: length 100 mm, widths 40-100 mm)."""

    kind: Literal["rectangle"] = "rectangle"
    length_mm: Real = Field(100.0, gt=0, le=500)
    width_mm: Real = Field(gt=0, le=500)

    @model_validator(mode="after")
    def _length_is_longer(self) -> RectangleScene:
        if self.width_mm > self.length_mm:
            raise ValueError(f"width_mm ({self.width_mm}) must not exceed length_mm ({self.length_mm})")
        return self


class PlateScene(StrictModel):
    """A plate at height h below a bending actuator's tip (paper, Fig. 1a-d). Rigid unless
    ``stiffness_n_per_mm`` is given (the soft plate of Fig. 2f-g)."""

    kind: Literal["plate"] = "plate"
    height_mm: Real = Field(ge=0, le=500)
    stiffness_n_per_mm: Real | None = Field(None, gt=0, le=1e6)


class ProfileScene(StrictModel):
    """A surface profile moving under the tip at constant speed (paper, Fig. 2h-i: 100 mm
    of sine or triangle surface scanned at 2 mm/s). The tip-surface distance is
    ``base_mm`` minus the surface height; motion starts ``delay_s`` after the scene is
    set (when the arm would start)."""

    kind: Literal["profile"] = "profile"
    shape: Literal["sine", "triangle", "flat"] = "sine"
    base_mm: Real = Field(10.0, ge=0, le=200)
    amplitude_mm: Real = Field(4.0, ge=0, le=100)
    period_mm: Real = Field(25.0, gt=0, le=1000)
    length_mm: Real = Field(100.0, gt=0, le=2000)
    speed_mm_s: Real = Field(2.0, gt=0, le=1000)
    delay_s: Real = Field(0.0, ge=0, le=10_000)

    def surface_mm(self, x_mm):
        """Surface height (mm) at position x along the scan; 0 outside [0, length]."""
        import numpy as np

        x = np.asarray(x_mm, dtype=float)
        phase = (x / self.period_mm) % 1.0
        if self.shape == "sine":
            z = 0.5 * self.amplitude_mm * (1 - np.cos(2 * np.pi * phase))
        elif self.shape == "triangle":
            z = self.amplitude_mm * (1 - np.abs(2 * phase - 1))
        else:
            z = np.zeros_like(x)
        return np.where((x >= 0) & (x <= self.length_mm), z, 0.0)

    def gap_mm(self, t_since_set_s):
        """Tip-to-surface distance (mm) at a time after the scene was set."""
        import numpy as np

        x = (np.asarray(t_since_set_s, dtype=float) - self.delay_s) * self.speed_mm_s
        return self.base_mm - self.surface_mm(x)


class SampleScene(StrictModel):
    """A silicone sample under a suction cup (paper, Methods "Suction cup")."""

    kind: Literal["sample"] = "sample"
    material: Literal["OO-50", "OO-30", "OO-10", "OOO-34"] | None = "OO-30"
    modulus_kpa: Real | None = Field(None, gt=0, le=1e6, description="overrides material")

    @property
    def modulus(self) -> float:
        """kPa"""
        return self.modulus_kpa if self.modulus_kpa is not None else SILICONE_MODULUS_KPA[self.material]


class PullScene(SampleScene):
    """A pull test: the cup on a sample, pulled with a force rising at ``rate_n_per_s``
    from ``delay_s`` after the scene is set, until it detaches (paper: load cell at 1 mm/s;
    mean detachment force 4.53 N on OO-30)."""

    kind: Literal["pull"] = "pull"
    rate_n_per_s: Real = Field(0.2, gt=0, le=100)
    delay_s: Real = Field(0.0, ge=0, le=10_000)

    def force_n(self, t_since_set_s):
        import numpy as np

        return np.clip((np.asarray(t_since_set_s, dtype=float) - self.delay_s) * self.rate_n_per_s, 0.0, None)


class StopperScene(StrictModel):
    """A stopper that blocks a muscle-driven joint at angle theta (paper, Fig. retrofit 1)."""

    kind: Literal["stopper"] = "stopper"
    angle_deg: Real = Field(ge=0, le=180)


class WallScene(StrictModel):
    """A rigid wall at distance L from the tip of a linear extension actuator."""

    kind: Literal["wall"] = "wall"
    distance_mm: Real = Field(ge=0, le=10_000)


Scene = Annotated[EmptyScene | CylinderScene | RectangleScene | PlateScene | ProfileScene | SampleScene
                  | PullScene | StopperScene | WallScene, Field(discriminator="kind")]

# scene kind -> (target field, unit) for calibration and sensing
TARGETS: dict[str, tuple[str, str]] = {
    "cylinder": ("diameter_mm", "mm"),
    "rectangle": ("width_mm", "mm"),
    "plate": ("height_mm", "mm"),
    "sample": ("modulus_kpa", "kPa"),
    "stopper": ("angle_deg", "deg"),
    "wall": ("distance_mm", "mm"),
}
