"""fluidsense characterise on the pressure-flow circuit (issue 36 item 1, method 2): the law
V_eq p_std = Pe v0 + c Pe (Pe + Pa) fitted to each cycle, its refusals (a law that bends,
a flow sensor at its rail, a leak seen as flow still going in), and the command line on a
simulated cell in virtual time.

(The proof over ten hidden actuators, too long for this tier: tests/system/test_characterise_flow.py.)
"""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
from fluidsense.common.units import KPA, ML
from fluidsense.controller.config import load_cell_config, load_profile
from fluidsense.controller.service import Controller
from fluidsense.drivers.registry import build_backend
from fluidsense.tasks import characterise as ch
from fluidsense.tasks.journal import journal_path
from support.cli import run_cli
from support.configs import profile_config
from support.harness import REPO, sim_config

START = "pneunet-bending-pressure-flow"
P_ATM = 101325.0


def _v_eq_ml(pe_kpa: float, v_side_ml: float, c: float) -> float:
    pe = pe_kpa * KPA
    return (pe * v_side_ml * ML + c * ML / KPA * pe * (pe + P_ATM)) / P_ATM / ML


def _synthetic(levels, cycles, v_side_ml, c, rng, sd_ml=0.08, bend=0.0, settled=0.0, rail_s=0.0):
    """Entries as measure() writes them for a pressure-flow cycle: each at its own Pe (the
    regulator's landing, 0.08 kPa sd), V_eq from the law plus a spread (and a bend, a leak's
    settled inflow or time at the rail when asked)."""
    out, cid = [], 0
    for lv in levels:
        for k in range(cycles):
            cid += 1
            pe = lv + rng.normal(0, 0.08)
            # a bend: the middle level off the law (a quadratic in Pe would be taken up by v0 and c)
            v = _v_eq_ml(pe, v_side_ml, c) + bend * (lv == levels[len(levels) // 2]) + rng.normal(0, sd_ml)
            out.append({"level_kpa": lv, "k": k, "cycle_id": cid, "p_eq_kpa": pe, "noise_kpa": 0.07,
                        "lag_s": None, "settle_s": 11.0, "rise_s": 2.3, "drift_kpa_per_s": rng.normal(0, 1e-4),
                        "drift_se_kpa_per_s": 1e-4, "rise_t_s": None, "v_eq_ml": v, "flow_peak_slpm": 0.03 * lv,
                        "flow_rail_s": rail_s if lv == levels[-1] else 0.0,
                        "flow_settled_slpm": settled + rng.normal(0, 1.5e-4), "flow_settled_se_slpm": 1.5e-4})
    return out


def test_the_fit_recovers_the_law_and_refusals_name_why():
    """Clean readings from the law: v0 and c within their intervals, written with the flow
    sensor's scale named. A law that bends beyond the spread, a cycle at the flow sensor's
    rail and a settled inflow (a leak): each refused with its reason."""
    prof = load_profile(REPO / "config" / "profiles" / f"{START}.yaml")
    rng = np.random.default_rng(5)
    levels = [4.1, 8.2, 12.4, 16.5, 20.6]
    res = ch.fit(_synthetic(levels, 4, 27.0, 0.93, rng), prof)
    v0, c = (next(f for f in res.fitted if f.field == n) for n in ("actuator.v0_ml", "actuator.compliance_ml_per_kpa"))
    assert v0.lo95 <= 27.0 <= v0.hi95 and c.lo95 <= 0.93 <= c.hi95, (v0, c)
    assert (c.hi95 - c.lo95) / 2 < 0.1 * c.value  # 0.08 ml of spread over a 16 kPa span says something
    assert "scaled by the flow sensor" in v0.how and "flow_sensor" in res.kept and "circuit.tank_l" not in res.kept
    assert res.residual_ml is not None and res.pure_error_ml == pytest.approx(0.08, rel=0.4)
    with pytest.raises(ch.FitRefused, match="does not fit"):
        ch.fit(_synthetic(levels, 4, 27.0, 0.93, rng, bend=0.5), prof)
    with pytest.raises(ch.FitRefused, match="read its rail in 4 cycle"):
        ch.fit(_synthetic(levels, 4, 27.0, 0.93, rng, rail_s=0.09), prof)
    with pytest.raises(ch.FitRefused, match="a leak: once settled"):
        ch.fit(_synthetic(levels, 4, 27.0, 0.93, rng, settled=0.01), prof)


def test_default_levels_stay_inside_the_flow_sensors_range():
    """The shipped profile's own 23.8 kPa puts 0.78 SLPM through its 1.83e9 path at the
    opening, past the HAFBLF0750's 0.75: the default sweep tops out where it is 90 % of it."""
    prof = load_profile(REPO / "config" / "profiles" / f"{START}.yaml")
    levels = ch.default_levels(prof)
    assert levels[-1] == pytest.approx(0.9 * 0.75 / 60e3 * 1.83e9 / KPA, abs=1e-3)
    assert levels[-1] < prof.sequence.p0_kpa
    assert levels[0] == pytest.approx(0.2 * levels[-1], abs=1e-3) and len(levels) == ch.DEFAULT_LEVELS


def test_a_leak_is_refused_in_the_plant(tmp_path):
    """A hidden actuator that leaks (1e11 Pa s/m^3 to the air): the regulator holds its
    pressure, so no drift shows, but the flow still going in does: refused naming the leak."""
    start = load_profile(profile_config(tmp_path, START))
    leaky = profile_config(tmp_path, START, circuit={"leak_resistance_pa_s_per_m3": 1.0e11})
    hidden_cfg = load_cell_config(sim_config(tmp_path, seed=3, profile=str(leaky)))
    cfg = hidden_cfg.model_copy(update={"profile": start})
    levels = ch.check_plan(start, [6.0, 12.0, 18.0], 2)
    journal = ch.CharacteriseJournal.open(journal_path(tmp_path / "out.yaml"), {"levels_kpa": levels, "cycles": 2},
                                          resume=False)

    async def main():
        ctrl = Controller(cfg, build_backend(cfg.driver, hidden_cfg.profile.hardware))
        await ctrl.start()
        try:
            return await ch.measure(ctrl.task_port, levels, 2, journal)
        finally:
            await ctrl.stop()

    entries = asyncio.run(main())
    with pytest.raises(ch.FitRefused, match="a leak: once settled"):
        ch.fit(entries, start)


def test_cli_writes_a_pressure_flow_profile(tmp_path, capsys):
    """characterise on a simulated pressure-flow cell (virtual time) writes a profile whose
    provenance holds the V_eq fit's residual and spread, names the flow sensor as the scale,
    and loads; the plan's levels are recorded."""
    cell = sim_config(tmp_path, profile=str(REPO / "config" / "profiles" / f"{START}.yaml"))
    out = tmp_path / "mine.yaml"
    run = run_cli(capsys, "characterise", "--config", cell, "--out", out, "--levels", "5,10,15,20", "--cycles", "2",
                  "--yes")
    assert run.returncode == 0, run.stderr
    assert "P-V fit (V_eq against Pe)" in run.stdout
    prof = load_profile(out)
    prov = prof.provenance
    assert prov.levels_kpa == [5.0, 10.0, 15.0, 20.0] and prov.residual_ml is not None and prov.pure_error_ml > 0
    assert {"actuator.v0_ml", "actuator.compliance_ml_per_kpa", "sequence.eq_sd_kpa"} <= {f.field for f in prov.fitted}
    assert "flow_sensor" in prov.kept and "circuit.valve_delay_s" in prov.kept
    assert prof.actuator.travel_mm_per_ml == 3.0  # contact: kept from the start
    assert "V_eq against Pe" in out.read_text()


def test_cli_refuses_a_sweep_past_the_flow_sensors_range(tmp_path, capsys):
    """A level whose opening flow passes the flow sensor's range (30 kPa: 0.98 SLPM against
    0.75): the cycles run, the fit is refused naming the rail, nothing is written."""
    cell = sim_config(tmp_path, profile=str(REPO / "config" / "profiles" / f"{START}.yaml"))
    out = tmp_path / "mine.yaml"
    run = run_cli(capsys, "characterise", "--config", cell, "--out", out, "--levels", "10,20,30", "--cycles", "2",
                  "--yes")
    assert run.returncode == 1, run.stderr
    assert "the flow sensor read its rail" in run.stderr and "at 30 kPa" in run.stderr, run.stderr
    assert not out.exists() and len(journal_path(out).read_text().splitlines()) == 1 + 6


def test_targets_are_refused_with_the_pressure_flow_circuit(tmp_path, capsys):
    cell = sim_config(tmp_path, profile=str(REPO / "config" / "profiles" / f"{START}.yaml"))
    run = run_cli(capsys, "characterise", "--config", cell, "--out", tmp_path / "m.yaml", "--targets", "10,20",
                  "--yes")
    assert run.returncode == 2 and "pressure-flow circuit it is not built yet" in run.stderr, run.stderr
