"""fluidsense characterise (issue 36 items 1 and 4): the fit against eq. 1, its refusals,
and the proof: simulated cells whose actuator differs from the shipped profile by known
amounts, characterised from the shipped profile, give back the hidden values within their
stated 95 % intervals.

(Its tests with real peers: tests/system/test_characterise.py.)
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from fluidsense.common.units import KPA, ML
from fluidsense.controller.config import load_profile
from fluidsense.tasks import characterise as ch
from fluidsense.tasks.journal import journal_path
from support.characterise import START, characterise_in_process, hidden_profile
from support.configs import profile_config
from support.cli import run_cli
from support.harness import REPO, sim_config



# ------------------------------------------------------------------ the model
def test_the_fit_model_is_the_simulators_equilibrium():
    """free_equilibrium (the fit's eq. 1 in closed form) against the simulator's own root
    search on the actuator's volume law, for both signs of P0."""
    from fluidsense.common.hardware import GripperActuator
    from fluidsense.common.scenes import EmptyScene
    from fluidsense.simulator.actuators import volume_law
    from fluidsense.simulator.equilibrium import equilibrium

    p_atm = 101325.0
    act = GripperActuator(v0_ml=87.0, compliance_ml_per_kpa=1.21)
    law = volume_law(act, EmptyScene(), p_atm)
    for p0_kpa in (20.0, 45.0, 63.0):
        ours = ch.free_equilibrium(p0_kpa * KPA, 0.3e-3, act.v0, act.compliance, p_atm)
        theirs = equilibrium(p0_kpa * KPA, 0.3e-3, law, p_atm)
        assert ours == pytest.approx(theirs, abs=1e-3), p0_kpa  # 1 mPa


def _synthetic(levels, cycles, v_side_ml, c_ml_kpa, sd_kpa, rng, bend=0.0, drift=0.0):
    """Entries as measure() writes them, from eq. 1 plus a spread (and a bend of the law or
    a drift when asked)."""
    out, cid = [], 0
    for lv in levels:
        pe = ch.free_equilibrium(lv * KPA, 0.3e-3, v_side_ml * ML, c_ml_kpa * ML / KPA, 101325.0) / KPA
        pe += bend * (lv / levels[-1]) ** 4
        for k in range(cycles):
            cid += 1
            out.append({"level_kpa": lv, "k": k, "cycle_id": cid, "p_eq_kpa": pe + rng.normal(0, sd_kpa),
                        "noise_kpa": 0.07, "lag_s": 0.013, "settle_s": 0.8, "rise_s": 0.1,
                        "drift_kpa_per_s": drift + rng.normal(0, 1e-3), "drift_se_kpa_per_s": 1e-3,
                        "rise_t_s": None})
    return out


def test_refusals_name_why():
    """Too few levels, a leak, a law that bends beyond the cycles' spread, a window before
    settling: each refused with its reason, and nothing is refused on clean readings."""
    prof = load_profile(REPO / "config" / "profiles" / f"{START}.yaml")
    rng = np.random.default_rng(3)
    levels = [25.2, 34.6, 44.1, 53.5, 63.0]
    clean = _synthetic(levels, 4, 100.0, 1.07, 0.04, rng)
    ch.fit(clean, prof)  # holds
    with pytest.raises(ch.FitRefused, match="too few levels: 2"):
        ch.fit([e for e in clean if e["level_kpa"] in levels[:2]], prof)
    with pytest.raises(ch.FitRefused, match="a leak"):
        ch.fit(_synthetic(levels, 4, 100.0, 1.07, 0.04, rng, drift=-0.02), prof)
    with pytest.raises(ch.FitRefused, match="does not fit"):
        ch.fit(_synthetic(levels, 4, 100.0, 1.07, 0.04, rng, bend=1.0), prof)
    slow = [{**e, "settle_s": 2.4} for e in clean]
    with pytest.raises(ch.FitRefused, match="settled only after 2.4"):
        ch.fit(slow, prof)


def test_bad_plans_are_refused_before_any_valve_moves(tmp_path):
    prof = load_profile(REPO / "config" / "profiles" / f"{START}.yaml")
    from fluidsense.common.errors import ConfigError

    with pytest.raises(ConfigError, match="at least 3 levels"):
        ch.check_plan(prof, [30, 63], 4)
    with pytest.raises(ConfigError, match="outside the profile's limits"):
        ch.check_plan(prof, [30, 50, 89.9], 4)
    with pytest.raises(ConfigError, match="--cycles 1"):
        ch.check_plan(prof, [30, 50, 63], 1)
    flow = load_profile(REPO / "config" / "profiles" / "pneunet-bending-flow-control.yaml")
    with pytest.raises(ConfigError, match="flow-control circuit .* is not characterised yet"):
        ch.check_plan(flow, [5, 10, 15], 4)


def test_a_leak_is_refused_in_the_plant(tmp_path):
    """A hidden actuator that leaks (a laminar leak of 1e11 Pa s/m^3 to the air): the fit is
    refused naming the leak."""
    path, _ = hidden_profile(tmp_path, 1, circuit={"leak_resistance_pa_s_per_m3": 1.0e11})
    start, entries = characterise_in_process(tmp_path, 1, path, cycles=2)
    with pytest.raises(ch.FitRefused, match="a leak"):
        ch.fit(entries, start)


def test_cli_refuses_a_leaking_actuator_and_writes_nothing(tmp_path, capsys):
    """A cell whose actuator leaks (1e11 Pa s/m^3 to the air): the cycles run, the fit is
    refused naming the leak, the exit code is docs/cli.md's, no profile is written and the
    cycles are kept."""
    from support.docs import documented_exit

    leaky = profile_config(tmp_path, START, circuit={"leak_resistance_pa_s_per_m3": 1.0e11})
    cell = sim_config(tmp_path, profile=str(leaky))
    out = tmp_path / "mine.yaml"
    run = run_cli(capsys, "characterise", "--config", str(cell), "--out", str(out), "--levels", "20,40,63", "--cycles", "2",
               "--yes")
    assert run.returncode == documented_exit("characterise", "the cycles ran but the fit does not hold") == 1
    assert "a leak: the settled free-air pressure falls" in run.stderr and "no profile written" in run.stderr
    assert not out.exists() and len(journal_path(out).read_text().splitlines()) == 1 + 6


def test_a_characterised_profile_is_one_calibrate_and_sense_take(tmp_path, capsys):
    """The written profile is a profile like a shipped one: ``calibrate --profile mine``
    (found as ./mine.yaml) calibrates it on a simulated cell, and ``sense`` with that
    calibration reads a 70 mm cylinder, which no target was, within its interval. The
    simulated cell runs the profile's own numbers, the fitted ones among them."""
    cell = sim_config(tmp_path, profile=str(REPO / "config" / "profiles" / f"{START}.yaml"))
    out = tmp_path / "mine.yaml"
    run = run_cli(capsys, "characterise", "--config", str(cell), "--out", str(out), "--levels", "20,40,63",
                  "--cycles", "2", "--yes")
    assert run.returncode == 0, run.stderr
    cal = tmp_path / "mine.json"
    run = run_cli(capsys, "calibrate", "--profile", "mine", "--values", "40,60,80,100", "--cycles", "3", "--out",
                  str(cal), "--yes", "--json", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert json.loads(cal.read_text())["profile"] == load_profile(out).name
    run = run_cli(capsys, "sense", "-k", str(cal), "--profile", "mine", "--scene", "cylinder", "--set",
                  "diameter_mm=70", "--json", "--yes", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    sensed = json.loads(run.stdout)
    assert sensed["status"] == "ok" and sensed["interval"][0] <= 70 <= sensed["interval"][1], sensed
