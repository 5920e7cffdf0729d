"""Every scene and sensing method of the paper, on the simulated cell in virtual time:
the physical direction and the size of each effect."""

from __future__ import annotations

import numpy as np
import pytest
from fluidsense.common.hardware import BendingActuator
from fluidsense.common.scenes import (
    CylinderScene,
    PlateScene,
    PullScene,
    RectangleScene,
    SampleScene,
    StopperScene,
)
from fluidsense.common.units import P_ATM
from fluidsense.simulator.actuators import contact_truth
from scipy import stats
from support.harness import cycles_over, profile_controller


def bench_truth(scene, p_eq_pa):
    """What a force gauge / dial indicator reads at the measured equilibrium pressure."""
    return contact_truth(BendingActuator(), scene, P_ATM, p_eq_pa)


def kpa(results, attr="p_eq"):
    return np.array([getattr(r, attr) for _, r, _ in results]) / 1e3


def test_plate_distance_tank_method_and_force():
    """Fig. 1b: P_eq falls as the plate moves away, about 0.04 kPa/mm; the force on the
    plate grows with P_eq (Fig. S force calibration)."""
    heights = [0, 10, 20, 30, 40]
    res = profile_controller("pneunet-bending", lambda c: cycles_over(c, [PlateScene(height_mm=h) for h in heights]))
    p = kpa(res)
    assert np.all(np.diff(p) < 0)
    fit = stats.linregress(heights, p)
    assert fit.slope == pytest.approx(-0.04, rel=0.25) and fit.rvalue**2 > 0.98
    force = np.array([bench_truth(scene, r.p_eq)["tip_force_n"] for scene, r, _ in res])
    assert np.all(force > 0) and stats.linregress(p, force).rvalue > 0.98


def test_plate_distance_pressure_control_with_flow_measurement():
    """Fig. 1c: more air flows into the actuator the further away the plate is."""
    heights = [0, 20, 40]
    res = profile_controller("pneunet-bending-pressure-flow",
                             lambda c: cycles_over(c, [PlateScene(height_mm=h) for h in heights]))
    v = np.array([r.v_eq for _, r, _ in res]) * 1e6  # ml
    assert np.all(np.diff(v) > 0)
    assert (v[-1] - v[0]) / 40 == pytest.approx(0.09, rel=0.3)  # ml/mm
    p = kpa(res)
    np.testing.assert_allclose(p, 23.8, atol=0.3)  # the regulator holds the pressure


def test_plate_distance_flow_control_with_pressure_measurement():
    """Fig. 1d: a fixed air volume, fed by the flow controller, ends at a lower pressure
    the further away the plate is."""
    heights = [0, 20, 40]
    res = profile_controller("pneunet-bending-flow-control",
                             lambda c: cycles_over(c, [PlateScene(height_mm=h) for h in heights]))
    p = kpa(res)
    assert np.all(np.diff(p) < 0) and (p[0] - p[-1]) > 1.0


def test_plate_distance_time_of_first_contact():
    """Fig. 2a-c: the further the plate, the later the first contact."""
    heights = [5, 15, 25, 35]
    res = profile_controller("pneunet-bending", lambda c: cycles_over(
        c, [PlateScene(height_mm=h) for h in heights], reference=True))
    tc = np.array([r.t_c_slope for _, r, _ in res])
    assert np.all(np.diff(tc) > 0) and tc[0] < 1.0 < tc[-1]


def test_rectangles_give_two_contact_times():
    """Fig. 2d-e: one finger pair meets the 100 mm length first, the other the width later;
    the narrower the block, the later the second contact; a square has one."""
    widths = [40, 60, 80, 100]
    res = profile_controller("pneunet-gripper-shape", lambda c: cycles_over(
        c, [RectangleScene(width_mm=w) for w in widths], reference=True))
    t1 = np.array([r.t_c_slope for _, r, _ in res])
    t2 = [r.t_c2 for _, r, _ in res]
    assert np.ptp(t1) < 0.1  # same length, same first contact
    assert t2[3] is None
    assert t2[0] > t2[1] > t2[2] > t1.max()


def test_soft_plate_is_indented_and_ranked_by_stiffness():
    """Fig. 2f-g: 5 mm above the plate, first contact at the same time whatever the
    stiffness; the softer the plate, the lower P_eq and the deeper the indentation."""
    plates = [PlateScene(height_mm=5), PlateScene(height_mm=5, stiffness_n_per_mm=0.65),
              PlateScene(height_mm=5, stiffness_n_per_mm=0.2)]
    res = profile_controller("pneunet-bending", lambda c: cycles_over(c, plates, reference=True))
    tc = np.array([r.t_c_slope for _, r, _ in res])
    p = kpa(res)
    dent = [bench_truth(scene, r.p_eq)["indentation_mm"] for scene, r, _ in res]
    assert np.ptp(tc) < 0.15
    assert p[0] > p[1] > p[2]
    assert dent[0] == 0.0 and 0 < dent[1] < dent[2]


def test_suction_cup_ranks_the_four_silicones_and_p0_tunes_resolution():
    """Fig. retrofit 2c-d: the softer the sample, the more it is drawn in and the less
    negative P_eq; a deeper tank vacuum gives a larger span."""
    samples = [SampleScene(material=m) for m in ("OO-50", "OO-30", "OO-10", "OOO-34")]

    async def body(ctrl):
        deep = await cycles_over(ctrl, samples)
        shallow = []
        for s in samples:
            await ctrl.scene.place(s)
            shallow.append(await ctrl.run_cycle(p0_kpa=-21.0))
        return deep, shallow

    deep, shallow = profile_controller("suction-cup", body)
    p = kpa(deep)
    assert np.all(np.diff(p) > 0)  # modulus falls along the list: P_eq rises towards 0
    span_shallow = (shallow[-1].p_eq - shallow[0].p_eq) / 1e3
    assert 1.0 < p[-1] - p[0] < 6.0  # Table 1: 1.3-5.9 kPa
    assert p[-1] - p[0] > 1.5 * span_shallow > 0


def test_suction_cup_pull_test_predicts_detachment():
    """Fig. retrofit 2e: pulling the isolated cup deepens its vacuum almost linearly with
    the force; it lets go at about 4.5 N after about 1.2 kPa."""

    async def body(ctrl):
        seq = ctrl.profile.sequence
        scene = PullScene(material="OO-30", rate_n_per_s=0.2, delay_s=seq.charge_s + seq.isolate_s + 20)
        await ctrl.scene.place(scene)
        res = await ctrl.run_cycle()
        return scene, res, await ctrl.scene.truth()

    scene, res, truth = profile_controller("suction-cup-pull", body)
    t_rel, p = res.trace
    t_abs = t_rel + res.t_open - res.t_start  # time since the scene was set
    detach_force = float(scene.force_n(truth["detached_at_s"] - res.t_start))
    assert 3.5 < detach_force < 5.5
    pulling = (scene.force_n(t_abs) > 0.2) & (t_abs < truth["detached_at_s"] - res.t_start - 0.5)
    fit = stats.linregress(scene.force_n(t_abs[pulling]), p[pulling] / 1e3)
    assert fit.slope < 0 and fit.rvalue**2 > 0.8
    drop = -fit.slope * detach_force
    assert 0.7 < drop < 1.8
    assert abs(p[-1]) < 1e3  # after letting go the cup is at atmosphere


@pytest.mark.parametrize("profile, span_kpa", [("filament-muscle", 1.0), ("mckibben-muscle", 6.0)])
def test_muscles_sense_the_stopper_angle(profile, span_kpa):
    """Fig. retrofit 1a-f: the further the joint may turn, the lower P_eq; over 0-30 deg the
    filament spans about 1 kPa, the McKibben about 6 kPa."""
    res = profile_controller(profile, lambda c: cycles_over(c, [StopperScene(angle_deg=a) for a in (0, 15, 30)]))
    p = kpa(res)
    assert np.all(np.diff(p) < 0)
    assert p[0] - p[-1] == pytest.approx(span_kpa, rel=0.3)


@pytest.mark.parametrize("profile, sign, slope, diameters", [
    ("tpu-bending", 1, None, [40, 70, 100]),
    ("srt-pneunet-gripper", 1, 0.04, [40, 70, 100]),
    ("piab-vacuum-gripper", -1, 0.08, [40, 60, 80]),
])
def test_retrofit_grippers_sense_cylinder_size(profile, sign, slope, diameters):
    """Fig. retrofit 1g-i and 2f-k, Table S1: P_eq moves away from atmosphere as D grows,
    at the paper's resolution where it gives one."""
    res = profile_controller(profile, lambda c: cycles_over(c, [CylinderScene(diameter_mm=d) for d in diameters]))
    p = kpa(res)
    assert np.all(np.diff(sign * p) > 0)
    if slope is not None:
        assert abs(p[-1] - p[0]) / (diameters[-1] - diameters[0]) == pytest.approx(slope, rel=0.25)
