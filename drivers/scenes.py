"""What is in front of the actuator (simulated cells only).

Plain data: the simulated plant turns a scene into a contact law for the actuator it
has. Each scene holds no more than its measurement needs.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from .models import StrictModel


class EmptyScene(StrictModel):
    """Nothing to touch: free actuation (the reference)."""

    kind: Literal["none"] = "none"


class CylinderScene(StrictModel):
    """A rigid cylinder of diameter D between the gripper's fingers."""

    kind: Literal["cylinder"] = "cylinder"
    diameter_mm: float = Field(gt=0, le=500)


class WallScene(StrictModel):
    """A rigid wall at distance L from the tip of a linear extension actuator."""

    kind: Literal["wall"] = "wall"
    distance_mm: float = Field(ge=0, le=10_000)


Scene = Annotated[EmptyScene | CylinderScene | WallScene, Field(discriminator="kind")]
