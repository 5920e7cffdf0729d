"""The simulated plant against the paper's equations (Methods, "Modeling")."""

from __future__ import annotations

import numpy as np
import pytest
from fluidsense.common.hardware import GripperActuator, LinearActuator
from fluidsense.common.scenes import CylinderScene, EmptyScene, WallScene
from fluidsense.common.units import KPA, LITRE, ML, P_ATM
from fluidsense.simulator.actuators import volume_law
from fluidsense.simulator.equilibrium import eq10_pressure, eq11_resolution
from fluidsense.simulator.gas import ATMOSPHERE, Network, Pipe, VolumeLaw
from fluidsense.simulator.plant import Plant


def tank_and_actuator(law: VolumeLaw, v_tank: float, p0_gauge: float, r: float = 1e8) -> Plant:
    """Tank charged to p0, actuator at atmosphere, valve opened at t = 0."""
    net = Network(["tank", "actuator"], [VolumeLaw.constant(v_tank), law],
                  [Pipe(0, 1, r, "valve", True, "valve")])
    return Plant(net, {"valve": True}, p_reg_abs=P_ATM, regulator_tau_s=0.05,
                 p_initial_abs={"tank": P_ATM + p0_gauge})


def settle(plant: Plant, t_end: float = 60.0) -> np.ndarray:
    state, _ = plant.sample(np.array([t_end]))
    return plant.pressures_abs(state)[:, 0]


# ------------------------------------------------------------------ volume law
@pytest.mark.parametrize("p_gauge", [-20e3, -1.0, 0.0, 3e3, 6.9e3, 6.91e3, 34.6e3, 250e3])
def test_volume_law_inverts_exactly(p_gauge):
    law = VolumeLaw([0.0, 6.9e3, 1e6], [100 * ML, 107.4 * ML, 107.4 * ML + 0.62e-9 * (1e6 - 6.9e3)])
    m = law.amount_at(p_gauge)
    assert law.pressure_abs(m) == pytest.approx(P_ATM + p_gauge, rel=1e-12, abs=1e-6)
    assert law.pressure_abs_array(np.array([m, m]))[1] == pytest.approx(P_ATM + p_gauge, rel=1e-12, abs=1e-6)


def test_volume_law_refuses_a_cavity_that_shrinks_under_pressure():
    with pytest.raises(ValueError, match="not fall in volume"):
        VolumeLaw([0.0, 1e3], [2e-4, 1e-4])


# --------------------------------------------------------------- paper eq. 1
@pytest.mark.parametrize("scene", [EmptyScene(), CylinderScene(diameter_mm=20), CylinderScene(diameter_mm=60),
                                   CylinderScene(diameter_mm=100)])
def test_equilibrium_satisfies_eq1(scene):
    """p0*v_tank + p_atm*v0 = p1*(v_tank + v1), absolute pressures, within 0.1 %."""
    act = GripperActuator()
    law = volume_law(act, scene, P_ATM)
    v_tank, p0 = 0.3 * LITRE, 63 * KPA
    p_tank, p_act = settle(tank_and_actuator(law, v_tank, p0))
    assert p_tank == pytest.approx(p_act, rel=1e-6)
    v1 = float(law.volume_at(p_act - P_ATM))
    lhs = (P_ATM + p0) * v_tank + P_ATM * act.v0
    rhs = p_act * (v_tank + v1)
    assert abs(lhs - rhs) / lhs < 1e-3


def test_gripper_defaults_match_the_worked_check():
    """paper-numbers.md worked check: empty grip at 34.6 kPa, |dv1/dD| about 0.13 ml/mm."""
    act = GripperActuator()
    p = {}
    v = {}
    for d in (None, 40, 100):
        law = volume_law(act, EmptyScene() if d is None else CylinderScene(diameter_mm=d), P_ATM)
        p[d] = settle(tank_and_actuator(law, 0.3 * LITRE, 63 * KPA))[1] - P_ATM
        v[d] = float(law.volume_at(p[d]))
    assert p[None] / KPA == pytest.approx(34.6, abs=0.1)
    dv_dd = (v[100] - v[40]) / 60 / ML
    assert dv_dd == pytest.approx(-0.13, abs=0.02)
    assert (p[100] - p[40]) / 60 / KPA == pytest.approx(0.04, rel=0.1)


# ------------------------------------------------------------ paper eq. 3
def test_flow_between_tank_and_actuator_is_laminar_eq3():
    """dm/dt of the tank equals -p_std*(p_tank - p_act)/r at any instant of the transient."""
    r = 2e8
    law = volume_law(GripperActuator(), EmptyScene(), P_ATM)
    plant = tank_and_actuator(law, 0.3 * LITRE, 63 * KPA, r=r)
    t = np.array([0.05, 0.05 + 1e-6])
    state, _ = plant.sample(t)
    p = plant.pressures_abs(state)
    dm_dt = (state[0, 1] - state[0, 0]) / 1e-6
    expected = -P_ATM * (p[0, 0] - p[1, 0]) / r
    assert dm_dt == pytest.approx(expected, rel=1e-3)


def test_time_constant_follows_the_resistor():
    """Ten times the resistance, about ten times slower (response time set by r)."""
    law = volume_law(GripperActuator(), EmptyScene(), P_ATM)
    half = []
    for r in (1e8, 1e9):
        plant = tank_and_actuator(law, 0.3 * LITRE, 63 * KPA, r=r)
        t = np.linspace(0, 20, 20001)
        p_act = plant.pressures_abs(plant.sample(t)[0])[1] - P_ATM
        half.append(t[np.argmax(p_act >= 0.5 * p_act[-1])])
    assert half[1] / half[0] == pytest.approx(10, rel=0.05)


def test_samples_do_not_depend_on_how_requests_are_split():
    law = volume_law(GripperActuator(), CylinderScene(diameter_mm=60), P_ATM)
    t = np.arange(0, 2000) * 1e-3
    a = tank_and_actuator(law, 0.3 * LITRE, 63 * KPA)
    b = tank_and_actuator(law, 0.3 * LITRE, 63 * KPA)
    for plant in (a, b):
        plant.schedule_valve(0.5, "valve", False)
        plant.schedule_valve(1.2, "valve", True)
    whole = a.sample(t)[0]
    parts = np.hstack([b.sample(t[i:i + 7])[0] for i in range(0, len(t), 7)])
    np.testing.assert_allclose(parts, whole, rtol=1e-9)
    # and the closed valve really stopped the flow in between
    p_act = a.pressures_abs(whole)[1]
    assert abs(p_act[1100] - p_act[600]) < 1.0


# ---------------------------------------------------- paper eq. 10 and 11
def linear_plant(act: LinearActuator, wall_mm: float | None, v_tank: float, p0: float) -> Plant:
    scene = EmptyScene() if wall_mm is None else WallScene(distance_mm=wall_mm)
    return tank_and_actuator(volume_law(act, scene, P_ATM), v_tank, p0)


def eq10(act: LinearActuator, wall: float, v_tank: float, p0_abs: float) -> float:
    return eq10_pressure(p0_abs - P_ATM, v_tank, act.area, act.l0, wall, P_ATM)


def eq11(act: LinearActuator, wall: float, v_tank: float, p0_abs: float) -> float:
    return eq11_resolution(p0_abs - P_ATM, v_tank, act.area, act.l0, wall, P_ATM)


@pytest.mark.parametrize("wall_mm", [5.0, 15.0, 25.0, 31.0])
def test_linear_actuator_matches_eq10_and_eq11_where_it_reaches_the_wall(wall_mm):
    act, v_tank, p0 = LinearActuator(), 0.1 * LITRE, 50 * KPA
    p1 = settle(linear_plant(act, wall_mm, v_tank, p0))[1]
    assert p1 == pytest.approx(eq10(act, wall_mm * 1e-3, v_tank, P_ATM + p0), rel=1e-4)
    h = 0.5
    lo = settle(linear_plant(act, wall_mm - h, v_tank, p0))[1]
    hi = settle(linear_plant(act, wall_mm + h, v_tank, p0))[1]
    numeric = (hi - lo) / (2 * h * 1e-3)
    assert numeric == pytest.approx(eq11(act, wall_mm * 1e-3, v_tank, P_ATM + p0), rel=0.02)


def test_linear_actuator_has_no_resolution_where_it_cannot_reach():
    """A stiff actuator never touches the wall: the numerical resolution is zero while
    eq. 11 (which assumes contact) still predicts one (paper, Fig. S modelV4h)."""
    act, v_tank, p0 = LinearActuator(stiffness_n_per_m=1e6), 0.1 * LITRE, 50 * KPA
    wall_mm = 30.0
    free = settle(linear_plant(act, None, v_tank, p0))[1]
    extension = (free - P_ATM) * act.area / act.stiffness_n_per_m
    assert extension < wall_mm * 1e-3  # it really stops short of the wall
    lo = settle(linear_plant(act, wall_mm - 0.5, v_tank, p0))[1]
    hi = settle(linear_plant(act, wall_mm + 0.5, v_tank, p0))[1]
    assert abs(hi - lo) < 1e-6
    assert abs(eq11(act, wall_mm * 1e-3, v_tank, P_ATM + p0)) > 1.0  # Pa/m: analytic says otherwise


def test_vent_returns_the_actuator_to_atmosphere():
    law = volume_law(GripperActuator(), EmptyScene(), P_ATM)
    net = Network(["tank", "actuator"], [VolumeLaw.constant(0.3 * LITRE), law],
                  [Pipe(0, 1, 1e8, "valve", True), Pipe(1, ATMOSPHERE, 1e8, "valve", False)])
    plant = Plant(net, {"valve": True}, P_ATM, 0.05, p_initial_abs={"tank": P_ATM + 63 * KPA})
    plant.schedule_valve(5.0, "valve", False)
    p = plant.pressures_abs(plant.sample(np.array([4.9, 30.0]))[0])
    assert p[1, 0] - P_ATM > 30 * KPA
    assert abs(p[1, 1] - P_ATM) < 1.0
    assert p[0, 1] - P_ATM > 30 * KPA  # the closed valve kept the tank's charge
