"""fluidsense characterise on a tank circuit with an ISO 6358 valve: where the rise cannot
show the valve's conductance (a polled trace, a journal without the sample period) it is
kept, said so, before any model runs.

(Its tests that fit the rise of hidden simulated cells, minutes of CPU:
tests/system/test_characterise_iso.py.)
"""

from __future__ import annotations

import numpy as np
import pytest
from fluidsense.common.units import KPA, ML
from fluidsense.controller.config import load_profile
from fluidsense.tasks import characterise as ch
from support.harness import REPO


def _iso_entries(dt_s, span_s=0.3):
    """Entries of the sorting cell (0.4 L tank, ISO valve, hose) from eq. 1, every rise
    ``span_s`` from 10 to 90 %, at sample period ``dt_s`` (None: a journal without it)."""
    rng = np.random.default_rng(5)
    out, cid = [], 0
    for lv in (12.8, 25.6, 38.4, 51.2, 64.0):
        pe = ch.free_equilibrium(lv * KPA, 0.4e-3, 148.0 * ML, 1.56 * ML / KPA, 101325.0) / KPA
        for k in range(3):
            cid += 1
            out.append({"level_kpa": lv, "k": k, "cycle_id": cid, "p_eq_kpa": pe + rng.normal(0, 0.04),
                        "noise_kpa": 0.07, "lag_s": 0.013, "settle_s": 0.8, "rise_s": 0.1,
                        "drift_kpa_per_s": rng.normal(0, 1e-3), "drift_se_kpa_per_s": 1e-3,
                        "rise_t_s": list(0.015 + np.linspace(0.0, span_s, 9) ** 1.3), "dt_s": dt_s})
    return out


def test_an_iso_valve_is_kept_where_the_rise_cannot_show_it():
    """The sorting cell's ISO valve: a polled trace (50 ms samples: the 10-90 % rise in 4-5 of
    them) and a journal without the sample period keep C, b and the delay, each said so,
    before any model runs; the fit of the volumes holds."""
    prof = load_profile(REPO / "config" / "profiles" / "sorting-gripper.yaml")
    polled = ch.fit(_iso_entries(0.05), prof)
    why = polled.kept["circuit.valve.sonic_conductance_dm3_per_s_bar"]
    assert "samples at the 50 ms sample period" in why and polled.kept["circuit.valve.critical_ratio"] == why
    assert "circuit.valve.sonic_conductance_dm3_per_s_bar" not in {f.field for f in polled.fitted}
    old = ch.fit(_iso_entries(None), prof)
    assert "sample period" in old.kept["circuit.valve_delay_s"]
    assert polled.value("actuator.v0_ml") == pytest.approx(100.08, rel=0.1)


def test_the_journal_keeps_the_sample_period():
    """A journal line keeps its trace's sample period (the ISO fit models the rise at it); a
    line written before it was kept reads as None."""
    line = _iso_entries(0.001)[0]
    assert ch.CharacteriseJournal.parse_entry(line)["dt_s"] == 0.001
    assert ch.CharacteriseJournal.parse_entry({k: v for k, v in line.items() if k != "dt_s"})["dt_s"] is None
    t = np.arange(0.0, 1.0, 0.002)
    p = 30e3 * (1 - np.exp(-t / 0.1))
    assert ch.read_trace(t, p, 30e3, 70.0, (0.8, 0.9))["dt_s"] == pytest.approx(0.002)
