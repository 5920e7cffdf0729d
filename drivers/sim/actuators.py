"""Actuator + scene -> piecewise-linear volume law ``v(p_gauge)``.

Each function is the smallest contact law that explains its measurement:
a free P-V line, and after contact a reduced compliance (rigid wall: none).
"""

from __future__ import annotations

from ..errors import ConfigError
from ..hardware import GripperActuator, LinearActuator
from ..scenes import CylinderScene, EmptyScene, WallScene
from ..units import KPA, ML, MM
from .gas import VolumeLaw

# Far breakpoint: beyond it the law extrapolates with its last slope, so any value works
# as long as it is above every pressure a profile allows.
_FAR_PA = 1000 * KPA


def gripper_law(act: GripperActuator, scene, p_atm: float) -> VolumeLaw:
    c = act.compliance
    if isinstance(scene, EmptyScene):
        return VolumeLaw([0.0, _FAR_PA], [act.v0, act.v0 + c * _FAR_PA], p_atm)
    if isinstance(scene, CylinderScene):
        growth_at_contact = (act.open_mm - scene.diameter_mm) / act.closing_mm_per_ml * ML
        c_after = act.wrap_ratio * c
        if growth_at_contact <= 0:  # wider than the open gripper: touching from the start
            return VolumeLaw([0.0, _FAR_PA], [act.v0, act.v0 + c_after * _FAR_PA], p_atm)
        p_contact = growth_at_contact / c
        v_contact = act.v0 + growth_at_contact
        return VolumeLaw([0.0, p_contact, p_contact + _FAR_PA],
                         [act.v0, v_contact, v_contact + c_after * _FAR_PA], p_atm)
    raise ConfigError(f"scene {scene.kind!r} does not apply to a gripper (use none or cylinder)")


def linear_law(act: LinearActuator, scene, p_atm: float) -> VolumeLaw:
    """Paper eq. 6: v = A*(l0 + p*A/k) until the tip reaches the wall at L, then A*(l0 + L)."""
    a, l0, k = act.area, act.l0, act.stiffness_n_per_m
    slope = a * a / k
    if isinstance(scene, EmptyScene):
        return VolumeLaw([0.0, _FAR_PA], [a * l0, a * l0 + slope * _FAR_PA], p_atm)
    if isinstance(scene, WallScene):
        wall = scene.distance_mm * MM
        p_contact = wall * k / a
        v_wall = a * (l0 + wall)
        if p_contact <= 0:
            return VolumeLaw.constant(v_wall, p_atm)
        return VolumeLaw([0.0, p_contact, p_contact + _FAR_PA], [a * l0, v_wall, v_wall], p_atm)
    raise ConfigError(f"scene {scene.kind!r} does not apply to a linear actuator (use none or wall)")


def volume_law(actuator, scene, p_atm: float) -> VolumeLaw:
    if isinstance(actuator, GripperActuator):
        return gripper_law(actuator, scene, p_atm)
    if isinstance(actuator, LinearActuator):
        return linear_law(actuator, scene, p_atm)
    raise ConfigError(f"no simulated model for actuator kind {actuator.kind!r}")
