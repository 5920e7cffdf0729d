"""Actuator + scene -> piecewise-linear volume law ``v(p_gauge)``.

Every actuator here (but the linear one of eq. 6) is a free P-V line whose compliance
drops at contact events: ``contacts`` lists, in order, the volume change at which
something is touched and the fraction of the free compliance that remains after it.
That is the whole contact model; each scene only says where its contacts are.
"""

from __future__ import annotations

from collections.abc import Sequence

from fluidsense.common.errors import ConfigError
from fluidsense.common.hardware import (
    BendingActuator,
    GripperActuator,
    LinearActuator,
    MuscleActuator,
    SuctionCup,
)
from fluidsense.common.scenes import (
    CylinderScene,
    EmptyScene,
    PlateScene,
    ProfileScene,
    PullScene,
    RectangleScene,
    SampleScene,
    StopperScene,
    WallScene,
)
from fluidsense.common.units import KPA, ML, MM
from fluidsense.simulator.gas import VolumeLaw

# Far breakpoint: beyond it a law extrapolates with its last slope, so any value works
# as long as it is above every pressure a profile allows.
_FAR_PA = 2000 * KPA


def _law(v0: float, c_free: float, contacts: Sequence[tuple[float, float]], p_atm: float,
         vacuum: bool = False, shift: float = 0.0) -> VolumeLaw:
    """Free line ``v0 + c_free*p`` whose slope drops at each contact.

    ``contacts``: (volume change in m^3 at which the contact happens, fraction of the free
    compliance that remains after it), in the order they happen. A change <= 0 means
    touching from the start. For a ``vacuum`` actuator the changes are shrinkage under
    negative pressure. ``shift`` adds a constant volume (a pulled suction cup).
    """
    sign = -1.0 if vacuum else 1.0
    p, v = [0.0], [v0]
    c, done = c_free, 0.0
    for change, ratio in contacts:
        if change > done and c > 0:
            p.append(p[-1] + sign * (change - done) / c)
            v.append(v0 + sign * change)
            done = change
        c = c_free * ratio
    # the last segment extends far; under vacuum no further than absolute zero
    far = _FAR_PA if not vacuum else max(0.99 * p_atm + p[-1], 1.0)
    p.append(p[-1] + sign * far)
    v.append(v[-1] + sign * c * far)
    if vacuum:  # VolumeLaw wants rising pressure; a collapsed cavity keeps a little volume
        p, v = p[::-1], [max(x, 1e-3 * v0) for x in v[::-1]]
    return VolumeLaw(p, [x + shift for x in v], p_atm)


def _soft_ratio(ratio_rigid: float, force_area: float, k_object_n_per_mm: float | None, travel_mm_per_ml: float,
                compliance: float) -> float:
    """Compliance fraction after contact with a soft object.

    Free growth splits into a part that moves the tip (a fraction ``1 - ratio_rigid``,
    which a rigid contact blocks) and a part that balloons the actuator. A soft object
    yields ``delta = F / k`` with ``F = force_area * (p - p_contact)``, and the tip follows
    it; that motion takes ``delta * (1 - ratio_rigid) / travel`` of volume, so the object
    adds ``force_area * (1 - ratio_rigid) / (k * travel)`` to the rigid contact's
    compliance (never beyond free).
    """
    if k_object_n_per_mm is None:
        return ratio_rigid
    k = k_object_n_per_mm * 1e3  # N/m
    travel = travel_mm_per_ml * MM / ML  # m of tip travel per m^3 of free growth
    return min(1.0, ratio_rigid + force_area * (1 - ratio_rigid) / (k * travel) / compliance)


def gripper_law(act: GripperActuator, scene, p_atm: float, t_since_set: float = 0.0) -> VolumeLaw:
    c = act.compliance
    vacuum = act.drive == "vacuum"

    def change_at(opening_mm: float) -> float:
        return (act.open_mm - opening_mm) / act.closing_mm_per_ml * ML

    if isinstance(scene, EmptyScene):
        contacts: list[tuple[float, float]] = []
    elif isinstance(scene, CylinderScene):
        ratio = _soft_ratio(act.wrap_ratio, act.force_area_mm2 * MM * MM, scene.stiffness_at(t_since_set),
                            act.closing_mm_per_ml, c)
        contacts = []
        if scene.offset_mm > 0:
            # one finger meets the off-centre object first and pushes it to the centre
            contacts.append((change_at(scene.diameter_mm + 2 * scene.offset_mm), act.push_ratio))
        contacts.append((change_at(scene.diameter_mm), ratio))
    elif isinstance(scene, RectangleScene):
        # one finger pair meets the length first; the other pair, the width
        contacts = [(change_at(scene.length_mm), (1 + act.wrap_ratio) / 2),
                    (change_at(scene.width_mm), act.wrap_ratio)]
    else:
        raise ConfigError(f"scene {scene.kind!r} does not apply to a gripper (none, cylinder, rectangle)")
    return _law(act.v0, c, contacts, p_atm, vacuum=vacuum)


def bending_law(act: BendingActuator, scene, p_atm: float, t_since_set: float = 0.0) -> VolumeLaw:
    if isinstance(scene, EmptyScene):
        return _law(act.v0, act.compliance, [], p_atm)
    if isinstance(scene, PlateScene):
        height, k_plate = scene.height_mm, scene.stiffness_n_per_mm
    elif isinstance(scene, ProfileScene):
        height, k_plate = max(float(scene.gap_mm(t_since_set)), 0.0), None
    else:
        raise ConfigError(f"scene {scene.kind!r} does not apply to a bending actuator (none, plate, profile)")
    ratio = _soft_ratio(act.contact_ratio, act.force_area_mm2 * MM * MM, k_plate, act.travel_mm_per_ml,
                        act.compliance)
    return _law(act.v0, act.compliance, [(height / act.travel_mm_per_ml * ML, ratio)], p_atm)


def suction_law(act: SuctionCup, scene, p_atm: float, t_since_set: float = 0.0) -> VolumeLaw:
    """Vacuum: the cup collapses and the sample is drawn in, both in proportion to |p|."""
    if isinstance(scene, EmptyScene):  # sealed on a rigid flat surface: the cup alone
        c = act.compliance
    elif isinstance(scene, SampleScene):  # PullScene is one too
        c = act.compliance + act.sample_bulge_ml_kpa / scene.modulus * ML / KPA
    else:
        raise ConfigError(f"scene {scene.kind!r} does not apply to a suction cup (none, sample, pull)")
    shift = 0.0
    if isinstance(scene, PullScene):
        shift = act.pull_compliance_ml_per_n * ML * float(scene.force_n(t_since_set))
    return _law(act.v0, c, [], p_atm, shift=shift)


def muscle_law(act: MuscleActuator, scene, p_atm: float) -> VolumeLaw:
    if isinstance(scene, EmptyScene):
        return _law(act.v0, act.compliance, [], p_atm)
    if isinstance(scene, StopperScene):
        return _law(act.v0, act.compliance, [(scene.angle_deg / act.deg_per_ml * ML, act.blocked_ratio)], p_atm)
    raise ConfigError(f"scene {scene.kind!r} does not apply to a muscle (none, stopper)")


def linear_law(act: LinearActuator, scene, p_atm: float) -> VolumeLaw:
    """Paper eq. 6: v = A*(l0 + p*A/k) until the tip reaches the wall at L, then A*(l0 + L)."""
    a, l0, k = act.area, act.l0, act.stiffness_n_per_m
    if isinstance(scene, EmptyScene):
        return _law(a * l0, a * a / k, [], p_atm)
    if isinstance(scene, WallScene):
        return _law(a * l0, a * a / k, [(a * scene.distance_mm * MM, 0.0)], p_atm)
    raise ConfigError(f"scene {scene.kind!r} does not apply to a linear actuator (none, wall)")


def contact_truth(actuator, scene, p_atm: float, p_gauge: float, t_since_set: float = 0.0) -> dict[str, float]:
    """What an instrumented bench would measure at this pressure: the tip force on a
    plate (force area times the pressure above contact) and the indentation of a soft
    one (force over plate stiffness)."""
    if not isinstance(actuator, BendingActuator) or not isinstance(scene, (PlateScene, ProfileScene)):
        return {}
    law = volume_law(actuator, scene, p_atm, t_since_set)
    # touching from the start: contact at atmospheric pressure
    p_contact = 0.0 if len(law.p_gauge) < 3 else float(law.p_gauge[1])
    above = max(p_gauge - p_contact, 0.0)
    out = {"tip_force_n": actuator.force_area_mm2 * MM * MM * above}
    if isinstance(scene, PlateScene):
        # a soft plate pushes back with k*delta = F
        k_plate = scene.stiffness_n_per_mm
        out["indentation_mm"] = 0.0 if k_plate is None else out["tip_force_n"] / k_plate
    return out


def contact_pressure(actuator, scene, p_atm: float) -> float | None:
    """Gauge pressure at which the actuator makes (full) contact with the scene, or None
    when the scene has nothing to touch."""
    if isinstance(scene, EmptyScene):
        return None
    law = volume_law(actuator, scene, p_atm)
    inner = law.p_gauge[1:-1] if len(law.p_gauge) > 2 else law.p_gauge[:1]
    inner = [p for p in inner if p != 0.0] or [0.0]
    # the last contact in the direction of actuation is the one that closes the grip
    vacuum = getattr(actuator, "drive", "positive") == "vacuum"
    return float(min(inner) if vacuum else max(inner))


def update_step(scene) -> float:
    """How often a moving scene's contact law is refreshed (s of sample time): fine enough
    for its own time scale, no finer (each refresh restarts the integrator)."""
    if isinstance(scene, CylinderScene) and scene.creeps:
        return max(scene.creep_s / 100.0, 0.01)
    return 0.01  # profile scan: 0.02 mm at 2 mm/s; pull test: 0.002 N at 0.2 N/s


def is_dynamic(scene) -> bool:
    """Scenes whose contact law changes with time after they are set."""
    return isinstance(scene, (ProfileScene, PullScene)) or (isinstance(scene, CylinderScene) and scene.creeps)


def volume_law(actuator, scene, p_atm: float, t_since_set: float = 0.0) -> VolumeLaw:
    if isinstance(actuator, GripperActuator):
        return gripper_law(actuator, scene, p_atm, t_since_set)
    if isinstance(actuator, BendingActuator):
        return bending_law(actuator, scene, p_atm, t_since_set)
    if isinstance(actuator, SuctionCup):
        return suction_law(actuator, scene, p_atm, t_since_set)
    if isinstance(actuator, MuscleActuator):
        return muscle_law(actuator, scene, p_atm)
    if isinstance(actuator, LinearActuator):
        return linear_law(actuator, scene, p_atm)
    raise ConfigError(f"no simulated model for actuator kind {actuator.kind!r}")
