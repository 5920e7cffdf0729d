"""Actuator dynamics: the damped volume state, contact timing, resistance and windows
(issue 17). Noise-free step responses on the simulated plant (virtual time)."""

from __future__ import annotations

import numpy as np
import pytest
from fluidsense.common.hardware import (
    BendingActuator,
    GripperActuator,
    Hardware,
    TankCircuit,
)
from fluidsense.common.scenes import CylinderScene, EmptyScene, PlateScene
from fluidsense.common.units import KPA, LITRE, P_ATM
from fluidsense.simulator.actuators import volume_law
from fluidsense.simulator.equilibrium import equilibrium
from fluidsense.simulator.gas import Network, Pipe, VolumeLaw
from fluidsense.simulator.plant import Plant
from fluidsense.simulator.timing import step_response, window_mean


def _bending(resistor: float, response_s: float = 0.05) -> Hardware:
    return Hardware(circuit=TankCircuit(tank_l=0.1, resistor_pa_s_per_m3=resistor),
                    actuator=BendingActuator(response_s=response_s))


def _gripper(response_s: float = 0.05) -> Hardware:
    return Hardware(circuit=TankCircuit(tank_l=0.4, resistor_pa_s_per_m3=7e6),
                    actuator=GripperActuator(response_s=response_s))


def test_inverse_law_round_trips_and_a_stop_is_stiff():
    law = volume_law(BendingActuator(), PlateScene(height_mm=20), P_ATM)
    for pg in (0.0, 5e3, 15e3, 30e3):
        assert law.pressure_for_volume(float(law.volume_at(pg))) == pytest.approx(pg, abs=1e-6)
    wall = VolumeLaw([0.0, 1e4, 2e4], [1e-4, 2e-4, 2e-4])  # a rigid stop after 10 kPa
    assert wall.pressure_for_volume(2e-4 + 1e-9) - 1e4 > 1e3 * (wall.pressure_for_volume(1.5e-4) - 5e3) / 5e3


def test_damped_plant_conserves_gas_and_settles_at_eq1():
    law = volume_law(GripperActuator(), CylinderScene(diameter_mm=60), P_ATM)
    damping = 0.2 / GripperActuator().compliance
    net = Network(["tank", "actuator"], [VolumeLaw.constant(0.3 * LITRE), law], [Pipe(0, 1, 1e8, "v", True)],
                  dampers={1: damping})
    p0 = 63 * KPA
    plant = Plant(net, {"v": False}, P_ATM, 0.05, p_initial_abs={"tank": P_ATM + p0})
    plant.schedule_valve(0.0, "v", True)
    state, _ = plant.sample(np.array([0.0, 0.05, 0.3, 30.0]))
    p = plant.pressures_abs(state)
    v_act = plant.volumes(state, "actuator")
    total = p[0] * 0.3 * LITRE + p[1] * v_act
    assert np.ptp(total) / total[0] < 1e-8  # mass conservation through the dashpot
    assert p[1, -1] - P_ATM == pytest.approx(equilibrium(p0, 0.3 * LITRE, law, P_ATM), abs=1.0)
    # early on the structure lags the law: the volume is behind where the pressure would put it
    assert v_act[1] < float(law.volume_at(p[1, 1] - P_ATM))


def test_a_lagging_actuator_overshoots_on_a_fast_circuit():
    """With almost no resistance the gas arrives before the fingers move: the pressure rises
    above its final value and falls back as the volume catches up."""
    slow = step_response(_gripper(0.2), EmptyScene(), 63.0, 2.0)
    quasi = step_response(_gripper(0.0), EmptyScene(), 63.0, 2.0)
    assert slow.p_act_kpa.max() > slow.p_act_kpa[-1] + 1.0
    assert quasi.p_act_kpa.max() <= quasi.p_act_kpa[-1] + 1e-3
    assert slow.p_act_kpa[-1] == pytest.approx(quasi.p_act_kpa[-1], abs=1e-3)


def test_contact_time_grows_with_distance_and_with_resistance():
    t_h = [step_response(_bending(1.8e9), PlateScene(height_mm=h), 49.9, 3.0).t_contact_s for h in (5, 15, 25, 35)]
    assert all(b > a for a, b in zip(t_h, t_h[1:]))
    t_r = [step_response(_bending(r), PlateScene(height_mm=20), 49.9, 6.0).t_contact_s for r in (5.7e8, 1.8e9, 7.3e9)]
    assert t_r[0] < t_r[1] < t_r[2] and all(t is not None for t in t_r)
    assert step_response(_bending(1.8e9), EmptyScene(), 49.9, 1.0).t_contact_s is None


def test_a_window_before_contact_cannot_separate_objects_after_contact_it_can():
    big = step_response(_gripper(), CylinderScene(diameter_mm=100), 64.0, 1.0)
    small = step_response(_gripper(), CylinderScene(diameter_mm=40), 64.0, 1.0)
    first = min(big.t_contact_s, small.t_contact_s)
    assert first > 0.02
    before = [window_mean(r, first - 0.012, 0.01) for r in (big, small)]
    after = [window_mean(r, 0.5, 0.05) for r in (big, small)]
    assert abs(before[0] - before[1]) < 1e-6  # the same free trajectory until the first touch
    assert after[0] - after[1] > 0.5  # the larger cylinder reads higher once both are held


def test_timing_section_is_a_ledger_and_keeps_its_disagreements(tmp_path):
    from lab.report.common import ledger_counts, ledger_problems
    from lab.report.sections.timing import timing

    sec = timing(tmp_path, 1)
    rows = {r["quantity"]: r for r in sec.rows}
    assert all(r["kind"] in ("fitted", "predicted") and r["source"] for r in sec.rows)
    assert ledger_problems(sec.rows) == []
    # the two sorting readings the gripper was built from are fitted, never counted as predictions
    assert {q for q, r in rows.items() if r["kind"] == "fitted"} == {
        "sorting reading at 5 s, D = 40 mm", "sorting reading at 5 s, D = 100 mm"}
    # verdicts without a published number are qualitative, whatever they show
    before = rows["a reading before contact cannot separate 40 from 100 mm"]
    assert (before["verdict"], before["holds"]) == ("qualitative", True)
    assert all(r["verdict"] == "qualitative" for q, r in rows.items() if "sorted by the reading" in q)
    assert sec.numbers["before_contact_gap_kpa"] < 1e-6 < 0.5 < sec.numbers["after_contact_gap_kpa"]
    fast = sec.numbers["fast_sorting_74_kpa"]
    assert [fast[str(d)] for d in (40, 60, 80, 100)] == sorted(fast.values())
    for r in sec.rows:  # a verdict is the tolerance applied, not an opinion
        if r["quantity"].startswith("fast sorting (") and "D =" in r["quantity"]:
            paper = float(r["paper"].split()[0])
            ours = float(r["ours"].split()[0])
            sd = float(r["paper"].split()[2])  # "38.21 +- 0.11 kPa (sd)": the paper's own spread
            assert (r["verdict"] == "match") == (abs(ours - paper) <= 2 * sd)
            assert r["verdict"] == "match" or r["why"]
    n = ledger_counts(sec.rows)
    assert n["fitted"] == 2 and n["predicted"] == len(sec.rows) - 2
    assert (tmp_path / "timing.png").stat().st_size > 10_000


def test_a_row_must_say_what_kind_it_is():
    from lab.report.common import Section

    sec = Section("x", "x")
    with pytest.raises(ValueError, match="kind"):
        sec.row("q", "1", "1", True, "", "Fig. 1", kind="tuned")
    with pytest.raises(ValueError, match="reason"):
        sec.row("q", "1 kPa", "2 kPa", False, "", "Fig. 1", kind="predicted", figures=("1 kPa",), tolerance="t")
