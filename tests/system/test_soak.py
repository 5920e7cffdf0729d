"""The soak benchmark, shortened: every sample reaches the pipeline with a slow
subscriber attached, and the report carries its figures (docs/soak.md has the 8 h run).

(Its in-process tests: tests/unit/test_soak.py.)
"""

from __future__ import annotations

import json
import subprocess
import sys
import pytest
from support.harness import REPO

from lab.bench.soak import SCENES


def test_shortened_soak_loses_no_sample_and_reports_its_figures():
    """Twelve virtual minutes, with the publisher's queue small enough that the slow
    subscriber overflows it within the warm-up: PUB drops for it, the pipeline nothing."""
    out = subprocess.run([sys.executable, "-m", "lab", "bench", "soak", "--virtual-hours", "0.2",
                          "--pub-hwm", "100", "--json"], cwd=REPO, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    rep = json.loads(out.stdout)
    assert rep["virtual_hours"] >= 0.2 and rep["wall_s"] > 0
    assert rep["cycles"] >= 6 and rep["cycles_failed"] == 0
    assert rep["samples_lost"] == 0 and rep["duplicated"] == 0
    assert rep["block_gaps"] == 0 and rep["source_missed"] == 0
    # sample k at k ms from 0: every slot up to the end accounted for, once
    assert rep["samples"] == rep["controller_samples"] == round(rep["virtual_hours"] * 3600 * 1000) + 1
    sub = rep["subscriber"]
    assert sub["got_end_mark"] and sub["received"] > 0
    assert sub["dropped"] > 0  # it really was too slow: PUB dropped for it ...
    assert sub["received"] + sub["dropped"] == sub["published_since_attach"]
    assert 0 < sub["pressure_samples"] < rep["samples"] and sub["pressure_duplicated"] == 0
    # ... and memory stayed flat once its queue was full (target for 8 h: <= 10 MB)
    assert rep["rss_initial_mb"] <= rep["rss_start_mb"] <= rep["rss_max_mb"]
    assert rep["memory_growth_mb"] == pytest.approx(rep["rss_end_mb"] - rep["rss_start_mb"])
    assert rep["memory_growth_mb"] <= 10
    assert rep["recording"]["files"] >= 1 and rep["recording"]["bytes"] > 0
    drift = rep["drift"]
    assert set(drift) == set(SCENES)
    for scene, d in drift.items():
        assert d["first_n"] >= 1 and d["last_n"] >= 1, scene
        assert 30 < d["p_eq_first_mean_kpa"] < 45, scene
        assert abs(d["last_minus_first_kpa"]) <= 3 * rep["noise_sd_kpa"], scene
    # the object raises P_eq above free air: the scenes really changed
    assert drift["cylinder-60"]["p_eq_first_mean_kpa"] > drift["none"]["p_eq_first_mean_kpa"] + 1
