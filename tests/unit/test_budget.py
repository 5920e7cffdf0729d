"""The parts' error budget (common/budget.py, simulator/budget.py, simulator/parts.py):
each piece drawn when and within what its part says, moving the plant as the model says,
and the widened accuracy it predicts (lab/bench/budget.py) reproducible from a small run.

Real parts: the simulated cell's plant and sensors, the profiles as shipped; nothing mocked."""

from __future__ import annotations

import numpy as np
import pytest
from fluidsense.cli.options import profile_path
from fluidsense.common.budget import PartsBudget
from fluidsense.common.hardware import ACTUATE, SUPPLY
from fluidsense.common.scenes import PlateScene
from fluidsense.common.units import KPA, P_ATM
from fluidsense.controller.config import load_profile
from fluidsense.simulator.actuators import volume_law
from fluidsense.simulator.cell import CellSettings, SimulatedCell
from fluidsense.simulator.equilibrium import equilibrium
from fluidsense.simulator.parts import FIGURES, SSC_34
from pydantic import ValidationError


def _hw(name: str, **budget):
    prof = load_profile(profile_path(name))
    hw = prof.hardware
    return prof, (hw.model_copy(update={"budget": PartsBudget(**budget)}) if budget else hw)


def _advance(cell: SimulatedCell, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    return cell.next_block(int(round(seconds * cell.cfg.rate_hz)))


def test_every_figure_says_where_it_comes_from_and_an_uncertain_one_its_range():
    for f in FIGURES:
        assert f.source and f.drawn, f
        assert f.status in ("datasheet", "paper", "recalled", "assumption"), f
        if f.status in ("recalled", "assumption"):
            assert f.range is not None and f.range[0] <= f.value <= f.range[1], f


def test_the_shipped_budgets_are_the_tables_figures():
    teb = next(f for f in FIGURES if f.part == SSC_34 and f.quantity.startswith("total error band"))
    for name in ("pneunet-bending", "pneunet-bending-flow-control"):
        prof = load_profile(profile_path(name))
        span = prof.sensor.range_kpa[1] - prof.sensor.range_kpa[0]
        assert prof.budget.sensor_zero_kpa == pytest.approx(teb.value / 100 * span, abs=0.005)
    assert load_profile(profile_path("pneunet-bending-flow-control")).budget.flow_controller_of_rate == 0.009
    assert load_profile(profile_path("pneunet-gripper")).budget == PartsBudget()  # the rest: unchanged


def test_a_budget_field_out_of_its_range_is_refused_with_its_name():
    with pytest.raises(ValidationError, match="flow_controller_of_rate"):
        PartsBudget(flow_controller_of_rate=0.9)


def test_the_session_zero_is_drawn_within_the_teb_once_per_session():
    prof, hw = _hw("pneunet-bending")
    teb = prof.budget.sensor_zero_kpa * KPA
    zeros = []
    for seed in range(60):
        cell = SimulatedCell(CellSettings(seed=seed), hw)
        zeros.append(cell.sensors["p_act"].offset - prof.sensor.offset_kpa * KPA)
        _advance(cell, 0.5)  # sampling does not redraw it
        assert cell.sensors["p_act"].offset - prof.sensor.offset_kpa * KPA == zeros[-1]
    zeros = np.array(zeros)
    assert np.all(np.abs(zeros) <= teb)
    assert zeros.max() > 0.5 * teb and zeros.min() < -0.5 * teb  # spread over the band, not a constant
    assert len(np.unique(zeros)) == len(zeros)


def test_a_profile_without_a_budget_draws_nothing_and_reads_as_before():
    _, hw = _hw("pneunet-bending")
    bare = hw.model_copy(update={"budget": PartsBudget()})
    a, b = SimulatedCell(CellSettings(seed=3), hw), SimulatedCell(CellSettings(seed=3), bare)
    assert b.draws.regulator_error_pa == 0 and b.draws.flow_controller_gain == 1.0
    assert b.sensors["p_act"].offset == pytest.approx(0.2 * KPA)
    # the other streams are the same with and without a budget: the same noise on the same samples
    ta, va = _advance(a, 0.2)
    tb, vb = _advance(b, 0.2)
    assert np.allclose(va[:, 0] - a.sensors["p_act"].offset, vb[:, 0] - b.sensors["p_act"].offset, atol=0.006 * KPA)


def test_the_regulators_session_error_moves_p_eq_as_eq1_says():
    """Two cells of one seed (the same per-cycle regulator draw), one with a 2 kPa
    session error bound: their P_eq differ by dP_eq/dP0 times the session draw."""
    prof, hw = _hw("pneunet-bending", regulator_setpoint_kpa=2.0)
    _, bare = _hw("pneunet-bending", regulator_setpoint_kpa=0.0)
    p0 = prof.sequence.p0_kpa * KPA
    ends = []
    for h in (hw, bare):
        cell = SimulatedCell(CellSettings(seed=11, scene=PlateScene(height_mm=20)), h)
        cell.command_setpoint(p0, 0.0)
        cell.command_valve(SUPPLY, True, 0.0)
        _advance(cell, 10.0)
        cell.command_valve(SUPPLY, False, cell.t_last)
        _advance(cell, 10.0)
        cell.command_valve(ACTUATE, True, cell.t_last)
        _advance(cell, 60.0)
        ends.append((cell.true_values()["p_act"], cell.regulator_error_pa, cell.draws.regulator_error_pa))
    (p_with, rep, session), (p_bare, rep_bare, none) = ends
    assert rep == rep_bare and none == 0.0 and abs(session) > 0.1 * KPA
    law = volume_law(prof.actuator, PlateScene(height_mm=20), P_ATM)
    tank = prof.circuit.tank_m3
    model = equilibrium(p0 + rep + session, tank, law, P_ATM) - equilibrium(p0 + rep, tank, law, P_ATM)
    assert p_with - p_bare == pytest.approx(model, rel=0.02)


def test_the_flow_controllers_accuracy_of_rate_is_one_gain_per_session():
    _, hw = _hw("pneunet-bending-flow-control")
    gains = [SimulatedCell(CellSettings(seed=s), hw).draws.flow_controller_gain for s in range(60)]
    assert all(abs(g - 1.0) <= 0.009 for g in gains)
    assert max(gains) - min(gains) > 0.009  # spread over the band


def test_the_flow_sensors_repeatability_is_redrawn_each_cycle_within_its_figure():
    _, hw = _hw("pneunet-bending-pressure-flow")
    cell = SimulatedCell(CellSettings(seed=5), hw)
    gains = []
    for _ in range(30):
        cell.command_valve(ACTUATE, True, cell.t_last)
        gains.append(cell.sensors["flow"].gain)
        _advance(cell, 0.05)
        cell.command_valve(ACTUATE, False, cell.t_last)
        _advance(cell, 0.05)
    assert all(abs(g - 1.0) <= 0.005 for g in gains) and len(set(gains)) == len(gains)


def test_a_plate_lands_within_the_placement_error_once_per_placement():
    _, hw = _hw("pneunet-bending")
    cell = SimulatedCell(CellSettings(seed=2), hw)
    landed = []
    for h in (10.0, 20.0, 30.0, 10.0):
        cell.set_scene(PlateScene(height_mm=h), cell.t_last)
        landed.append(cell.scene.height_mm)
        assert abs(cell.scene.height_mm - h) <= 0.5
        cell.set_scene(PlateScene(height_mm=h), cell.t_last)  # the same setting again: not moved
        assert cell.scene.height_mm == landed[-1]
    assert landed[0] != landed[3]  # set again later: another landing
    assert len({round(x - h, 9) for x, h in zip(landed, (10, 20, 30, 10))}) == 4


def test_a_small_held_out_run_reproduces_the_widened_accuracy_within_its_sampling_error():
    """The budget's prediction (lab/bench/budget.py) for flow control, where the flow
    controller's accuracy dominates: 200 held-out sessions against 2000. The 95th
    percentile of |error| from n trials has a relative sampling sd of about
    sqrt(0.05*0.95/n)/(f(q)*q); for these errors about 7 % at n = 200: allow 3 sd."""
    from lab.bench.budget import predict

    full = predict("flow_control", n_cal=40, n_test=50, seed=1)
    small = predict("flow_control", n_cal=10, n_test=20, seed=2)
    assert full["trials"] == 2000 and small["trials"] == 200
    assert small["abs_error_95_mm"] == pytest.approx(full["abs_error_95_mm"], rel=0.21)
    # and the budget widened it: the per-cycle parts alone give far less
    per_cycle = predict("flow_control", n_cal=10, n_test=20, seed=2,
                        on=frozenset({"flow controller repeatability (per cycle)", "placement (per target)",
                                      "sensor noise and resolution over the window (per sample)"}))
    assert per_cycle["abs_error_95_mm"] < 0.6 * full["abs_error_95_mm"]


@pytest.mark.parametrize("method", ["tank", "pressure_flow", "flow_control"])
def test_the_session_term_is_the_drive_error_the_static_plant_shows(method):
    """Profile.session_rel_sd takes every feature to scale with its drive (first order); on
    the static plant, over the session draws alone, the feature's relative sd is within
    20 % of it at both ends and mid range (2000 draws: 1.6 % sampling sd)."""
    from lab.bench.budget import SOURCES, Plant

    quiet = Plant(method, frozenset({SOURCES[1], SOURCES[2]}))
    term = quiet.prof.session_rel_sd
    assert term > 0
    rng = np.random.default_rng(7)
    for h in (0.0, 20.0, 40.0):
        ys = np.array([quiet.cycle(rng, quiet.session(rng), h) for _ in range(2000)])
        assert 0.8 < float(np.std(ys) / np.mean(ys)) / term < 1.25, (h, np.std(ys) / np.mean(ys), term)


@pytest.mark.parametrize("method", ["tank", "pressure_flow", "flow_control"])
def test_intervals_and_no_object_with_the_session_term_hold_in_fresh_sessions(method):
    """The issue's criterion on the static plant: 95 % intervals hold the truth in 90-99 %
    of 2000 held-out fresh sessions (40 calibrations). Without the term, flow control's
    held 57 %: its per-session part (the flow controller's accuracy of rate) dominates."""
    from lab.bench.budget import predict

    pred = predict(method, n_cal=40, n_test=50, seed=1)
    assert 0.90 <= pred["coverage95"] <= 0.99, pred
    if method == "flow_control":
        assert pred["coverage95_own_session_only"] < 0.7, pred
    # and "no object" holds in a fresh session: the free level moves with the set-up as every
    # reading does. Without the term an empty flow-controlled actuator claimed an object in
    # 12 % of fresh sessions. (Pressure control keeps 0.75 %, above the rule's 1 in 740:
    # its free sd comes from 7 cycles, whose t tail at 3 sd is heavier; docs/physics.md.)
    assert pred["empty_read_as_object"] <= 0.01, pred
    assert pred["plate_at_39_5_read_as_nothing"] <= 0.001, pred
    if method == "flow_control":
        assert pred["empty_read_as_object"] <= 0.005 < 0.05 < pred["empty_read_as_object_own_session_only"], pred
