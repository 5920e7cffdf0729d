"""Gas thermodynamics and the field's flow elements against their analytic limits.

The energy balance per volume (``simulator/gas.py``) must reduce to the isothermal model
when the wall time constant goes to 0 and to an adiabatic (isentropic) expansion when it
goes to infinity; a closed exchange conserves mass, and energy when adiabatic; ISO 6358
and the hose give their textbook formulas. Short virtual runs only.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from fluidsense.common.hardware import GripperActuator
from fluidsense.common.scenes import CylinderScene
from fluidsense.common.units import KPA, LITRE, ML, P_ATM
from fluidsense.simulator.actuators import volume_law
from fluidsense.simulator.elements import (
    DM3_PER_S_BAR,
    GAMMA,
    LAMINAR_RATIO,
    MU_AIR,
    P_ANR,
    bore_wall_time_s,
    hose_amount_flow,
    iso6358_amount_flow,
    iso6358_factor,
    tank_wall_time_s,
)
from fluidsense.simulator.gas import ATMOSPHERE, Network, Pipe, VolumeLaw
from fluidsense.simulator.plant import Plant

V_TANK = 0.4 * LITRE
P0 = 74 * KPA


def _plant(law: VolumeLaw, thermal: dict[int, float] | None, link: Pipe | None = None,
           dampers: dict[int, float] | None = None) -> Plant:
    link = link or Pipe(0, 1, 3e7, "valve", True, "valve")
    net = Network(["tank", "actuator"], [VolumeLaw.constant(V_TANK), law], [link], thermal=thermal,
                  dampers=dampers)
    return Plant(net, {"valve": True}, p_reg_abs=P_ATM, regulator_tau_s=0.05, p_initial_abs={"tank": P_ATM + P0})


def _gripper_law():
    return volume_law(GripperActuator(), CylinderScene(diameter_mm=60), P_ATM)


def test_thermal_model_tends_to_the_isothermal_one_as_the_wall_time_constant_goes_to_zero():
    t = np.linspace(0.0, 0.5, 26)
    iso = _plant(_gripper_law(), None)
    fast_wall = _plant(_gripper_law(), {0: 1e-4, 1: 1e-4})
    p_iso = iso.pressures_abs(iso.sample(t)[0])
    p_wall = fast_wall.pressures_abs(fast_wall.sample(t)[0])
    # the temperature lags the wall by about tau * dT/dt: 1e-4 s x a few hundred K/s -> < 0.1 K
    assert np.max(np.abs(p_wall - p_iso)) < 0.05 * KPA
    slower = _plant(_gripper_law(), {0: 1e-3, 1: 1e-3})
    p_slower = slower.pressures_abs(slower.sample(t)[0])
    assert np.max(np.abs(p_slower - p_iso)) > np.max(np.abs(p_wall - p_iso))  # converges, not coincides


def test_adiabatic_tank_expands_isentropically():
    """A rigid tank blowing down to the air with no heat exchange: T/T0 = (p/p0)^((gamma-1)/gamma)."""
    net = Network(["tank"], [VolumeLaw.constant(V_TANK)], [Pipe(0, ATMOSPHERE, 1e8, "valve", True, "vent")],
                  thermal={0: 1e12})
    plant = Plant(net, {"valve": True}, p_reg_abs=P_ATM, regulator_tau_s=0.05, p_initial_abs={"tank": P_ATM + P0})
    state, _ = plant.sample(np.array([0.0, 0.2, 1.0]))
    p = plant.pressures_abs(state)[0]
    theta = net.theta(state)[0]
    assert p[-1] < P_ATM + 0.6 * P0  # it did blow down
    np.testing.assert_allclose(theta, (p / (P_ATM + P0)) ** ((GAMMA - 1) / GAMMA), rtol=1e-6)


@pytest.mark.parametrize("damped", [False, True])
def test_closed_adiabatic_exchange_conserves_mass_and_energy(damped):
    """Tank into a rigid volume (no work): sum of m and of p*v (the internal energy x
    (gamma - 1)) stay what they were; with a damped compliant actuator mass still does."""
    if damped:
        act = GripperActuator()
        law, dampers = _gripper_law(), {1: 0.05 / act.compliance}
    else:
        law, dampers = VolumeLaw.constant(150 * ML), None
    plant = _plant(law, {0: 1e12, 1: 1e12}, dampers=dampers)
    state, _ = plant.sample(np.array([0.0, 0.05, 0.3, 2.0]))
    net = plant.net
    m = state[net.amount_slot(0)] + state[net.amount_slot(1)]
    np.testing.assert_allclose(m, m[0], rtol=1e-7)
    if not damped:
        e = state[0] + state[1]
        np.testing.assert_allclose(e, e[0], rtol=1e-7)
        theta = net.theta(state)[:, -1]
        assert theta[0] < 0.97 and theta[1] > 1.03  # the tank cooled, the receiver warmed


def test_with_a_finite_wall_the_exchange_settles_at_the_isothermal_equilibrium():
    law = _gripper_law()
    iso = _plant(law, None)
    wall = _plant(law, {0: 0.3, 1: 0.05})
    t = np.array([0.3, 8.0])
    p_iso = iso.pressures_abs(iso.sample(t)[0])[1]
    p_wall = wall.pressures_abs(wall.sample(t)[0])[1]
    assert abs(p_wall[0] - p_iso[0]) > 0.3 * KPA  # early: the cold tank holds the reading down
    assert p_wall[0] < p_iso[0]
    assert p_wall[1] == pytest.approx(p_iso[1], abs=0.002 * KPA)  # eq. 1 at the wall temperature


# ------------------------------------------------------------------- ISO 6358
C_SI = 0.3 * DM3_PER_S_BAR


@pytest.mark.parametrize("b", [0.15, 0.3, 0.5])
def test_iso6358_choked_and_subsonic(b):
    p1 = 200e3
    choked = P_ANR * C_SI * p1
    assert iso6358_amount_flow(C_SI, b, p1, 0.9 * b * p1) == pytest.approx(choked, rel=1e-12)
    assert iso6358_amount_flow(C_SI, b, p1, b * p1) == pytest.approx(choked, rel=1e-12)
    r = 0.5 * (b + 1.0)
    ellipse = math.sqrt(1 - ((r - b) / (1 - b)) ** 2)
    assert iso6358_amount_flow(C_SI, b, p1, r * p1) == pytest.approx(choked * ellipse, rel=1e-12)
    # hot upstream gas: less mass for the same C (sqrt(T0/T1))
    assert iso6358_amount_flow(C_SI, b, p1, r * p1, theta_a=1.21) == pytest.approx(choked * ellipse / 1.1, rel=1e-12)
    # reversed: the same flow the other way
    assert iso6358_amount_flow(C_SI, b, r * p1, p1) == pytest.approx(-choked * ellipse, rel=1e-12)
    # continuous into the laminar region, and zero at equal pressures
    lo, hi = iso6358_factor(LAMINAR_RATIO - 1e-12, b), iso6358_factor(LAMINAR_RATIO + 1e-12, b)
    assert hi == pytest.approx(lo, rel=1e-6)
    assert iso6358_amount_flow(C_SI, b, p1, p1) == 0.0


def test_hose_is_poiseuille_when_slow_and_blasius_when_fast():
    d, length, p = 4.3e-3, 3.3, 140e3
    dp = 1.0  # Pa: Re far below 1000
    poiseuille = (math.pi * d**4 / (128 * MU_AIR * length)) * dp * (p + 0.5 * dp)
    assert hose_amount_flow(d, length, p + dp, p) == pytest.approx(poiseuille, rel=1e-6)
    dp = 20e3  # a fast fill: turbulent, less than Poiseuille would pass
    flow = hose_amount_flow(d, length, p + dp, p)
    rho = (p + dp / 2) / (287.05 * 293.15)
    v = flow / ((p + dp / 2) * math.pi * d**2 / 4)
    re = rho * v * d / MU_AIR
    assert re > 2300
    f = 0.3164 * re**-0.25
    assert f * length / d * rho * v**2 / 2 == pytest.approx(dp, rel=1e-9)
    assert hose_amount_flow(d, length, p, p + dp) == pytest.approx(-flow, rel=1e-12)


def test_wall_time_constants_scale_as_their_correlations_say():
    # natural convection: larger tanks are slower (V/A grows faster than h falls)
    assert tank_wall_time_s(0.1 * LITRE, 165e3) < tank_wall_time_s(0.4 * LITRE, 165e3) < tank_wall_time_s(
        0.75 * LITRE, 165e3)
    # a larger temperature difference drives more convection: faster
    assert tank_wall_time_s(0.4 * LITRE, 165e3, delta_t_k=30) < tank_wall_time_s(0.4 * LITRE, 165e3, delta_t_k=3)
    # conduction in a bore goes as its radius squared
    assert bore_wall_time_s(8e-3, 140e3) == pytest.approx(4 * bore_wall_time_s(4e-3, 140e3), rel=1e-12)


# ------------------------------------------------------------ the configured circuit
def _sorting_hw(**circuit):
    from fluidsense.common.hardware import GripperActuator, Hardware, TankCircuit

    circuit = {"resistor_pa_s_per_m3": 0.0, **circuit}
    c = TankCircuit(tank_l=0.4, valve={"sonic_conductance_dm3_per_s_bar": 0.3, "critical_ratio": 0.3},
                    hose={"bore_mm": 4.3, "length_m": 3.3}, **circuit)
    return Hardware(circuit=c, actuator=GripperActuator(v0_ml=100.08, compliance_ml_per_kpa=1.56, wrap_ratio=0.78,
                                                        closing_mm_per_ml=1.885))


def test_a_bad_thermal_model_is_refused_with_the_field_named():
    from fluidsense.common.hardware import TankCircuit
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match="thermal.model"):
        TankCircuit(thermal={"model": "adiabatic"})
    with pytest.raises(ValidationError, match="bore_mm"):
        TankCircuit(hose={"bore_mm": -4.3, "length_m": 3.3})


def test_a_resistor_behind_an_iso_valve_slows_the_fill_and_keeps_the_equilibrium():
    from fluidsense.simulator.timing import step_response

    scene = CylinderScene(diameter_mm=60)
    fast = step_response(_sorting_hw(), scene, 64.0, 12.0, dt_s=5e-3)
    slow = step_response(_sorting_hw(resistor_pa_s_per_m3=5.7e8), scene, 64.0, 12.0, dt_s=5e-3)
    assert slow.t_contact_s > 2 * fast.t_contact_s
    # the 0.2 ml between valve and resistor holds gas too: 0.1 % of the volume, ~0.01 kPa
    assert slow.p_act_kpa[-1] == pytest.approx(fast.p_act_kpa[-1], abs=0.02)


def test_the_sensor_at_the_valve_end_leads_the_fingers_and_agrees_at_rest():
    from fluidsense.simulator.timing import step_response

    scene = CylinderScene(diameter_mm=60)
    at_valve = step_response(_sorting_hw(), scene, 64.0, 1.5, dt_s=2e-3)
    at_fingers = step_response(_sorting_hw().model_copy(update={"circuit": _sorting_hw().circuit.model_copy(
        update={"hose": _sorting_hw().circuit.hose.model_copy(update={"sensor_at": "actuator"})})}),
        scene, 64.0, 1.5, dt_s=2e-3)
    early = (at_valve.t_s > 0.015) & (at_valve.t_s < 0.05)
    assert np.all(at_valve.p_act_kpa[early] > at_fingers.p_act_kpa[early])  # the hose delays the fingers
    assert at_valve.p_act_kpa[-1] == pytest.approx(at_fingers.p_act_kpa[-1], abs=1e-3)


def test_the_sorting_gripper_refits_to_its_two_readings_through_whichever_model_it_uses():
    from fluidsense.simulator.band import FIT_READINGS, P0_SLOW_KPA, SLOW_WINDOW, refit
    from fluidsense.simulator.timing import step_response, window_mean

    fitted = refit(_sorting_hw())
    for d, reading in FIT_READINGS.items():
        resp = step_response(fitted, CylinderScene(diameter_mm=d), P0_SLOW_KPA, sum(SLOW_WINDOW) + 0.01)
        assert window_mean(resp, *SLOW_WINDOW) == pytest.approx(reading, abs=2e-3)
    # isothermal, the hose and the ISO valve change the 5 s readings little: near the profile's own fit
    assert fitted.actuator.compliance_ml_per_kpa == pytest.approx(1.56, rel=0.03)
    assert fitted.actuator.wrap_ratio == pytest.approx(0.78, rel=0.03)
