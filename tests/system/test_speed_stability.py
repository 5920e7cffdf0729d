"""Speed against accuracy and stability: the committed figures are what the benchmarks
produce, and the findings they rest on hold in virtual time.

(Its in-process tests: tests/unit/test_speed_stability.py.)
"""

from __future__ import annotations

import json
from itertools import combinations

import numpy as np
import pytest
from support.harness import REPO

from lab.bench import speed_accuracy as SA
from lab.bench import stability as ST
from lab.bench.stability_report import rounded


def _close(a, b):
    if isinstance(a, float) and isinstance(b, (int, float)):
        return a == pytest.approx(b, rel=2e-3, abs=1e-6)
    return a == b


@pytest.fixture(scope="module")
def committed_sa():
    return json.loads((REPO / "docs" / "speed-accuracy" / "results.json").read_text())


def _binomial_margin(p: float, n: int) -> float:
    """Two sampling sd of a fraction of n, plus one trial (so that p = 0 or 1 still allows one)."""
    return 2 * np.sqrt(p * (1 - p) / n) + 1 / n


def _same_within_sampling_error(fresh, committed, n: int) -> None:
    """What a rerun on another CPU must give again: not every digit (an early fit a few samples
    after contact is ill-conditioned, and OpenBLAS's kernels differ in rounding, so one trial may
    decide on one CPU and not on another), but whether a row decides where the committed one is
    clear of the DECIDED line, each fraction, 95th percentile and bias within its sampling error,
    and the order of the methods at each decision time where the committed gap is wider than
    that error."""
    rel = 2 * SA.same_as(n)  # two standard errors of the difference of two 95th percentiles
    for a, b in zip(fresh, committed):
        what = (b["method"], b["decision_time_s"], a, b)
        assert abs(a["decided_fraction"] - b["decided_fraction"]) <= _binomial_margin(b["decided_fraction"], n), what
        if abs(b["decided_fraction"] - SA.DECIDED) > _binomial_margin(SA.DECIDED, n):
            assert (a["decided_fraction"] >= SA.DECIDED) == (b["decided_fraction"] >= SA.DECIDED), what
        if b["decided_fraction"] >= SA.DECIDED + _binomial_margin(SA.DECIDED, n):
            assert a["err95_mm"] == pytest.approx(b["err95_mm"], rel=rel), what
            se_mean = b["err95_mm"] / 1.96 / np.sqrt(n)  # the 95th percentile of |e| is ~1.96 sd
            assert abs(a["bias_mm"] - b["bias_mm"]) <= 2 * np.sqrt(2) * se_mean, what
    for td in {r["decision_time_s"] for r in committed}:
        sure = [i for i, r in enumerate(committed) if r["decision_time_s"] == td
                and r["decided_fraction"] >= SA.DECIDED + _binomial_margin(SA.DECIDED, n)]
        for i, j in combinations(sure, 2):
            lo, hi = sorted((committed[i]["err95_mm"], committed[j]["err95_mm"]))
            if hi > lo * (1 + 2 * rel):  # clearly apart: the rerun keeps them in this order
                ci, cj = committed[i]["err95_mm"], committed[j]["err95_mm"]
                assert (fresh[i]["err95_mm"] < fresh[j]["err95_mm"]) == (ci < cj), (td, fresh[i], fresh[j])


def test_speed_accuracy_reproduces_one_scene_and_says_it_against_the_floor(committed_sa):
    """The committed run's first CHECK_TRIALS trials of one scene, recomputed: the same
    cells, in the same order, as the committed 200 (its ``check`` rows come from them)."""
    check = committed_sa["check"]
    assert (check["scene"], check["circuit"], check["trials"]) == (*SA.CHECK_PAIR, SA.CHECK_TRIALS)
    res = SA.run_bench(trials=SA.CHECK_TRIALS, seed=committed_sa["seed"], only=SA.CHECK_PAIR,
                       response_s=committed_sa["response_s"])
    fresh = SA._round(res["rows"])
    assert SA._round(res["check"]["rows"]) == fresh  # a run of CHECK_TRIALS trials is its own check
    assert len(fresh) == len(check["rows"]) == len(SA.decision_times(res["floors"]["gripper-cylinder fast"])) * 5
    assert [(r["method"], r["decision_time_s"]) for r in fresh] == [(r["method"], r["decision_time_s"])
                                                                   for r in check["rows"]]
    _same_within_sampling_error(fresh, check["rows"], SA.CHECK_TRIALS)
    floor = committed_sa["floors"]["gripper-cylinder fast"]
    assert all(_close(res["floors"]["gripper-cylinder fast"][k], floor[k]) for k in floor)
    # the actuator lag is in the scene: without it the farthest cylinder is touched far sooner
    assert SA.floor("gripper-cylinder", "fast", response_s=0.0)["contact_s"] < 0.8 * floor["contact_s"]
    first = SA.earliest(committed_sa["rows"], committed_sa["trials"])
    decided = [e for e in first if e["decision_time_s"] is not None]
    assert {(e["scene"], e["circuit"]) for e in decided} == {(s, c) for s in SA.SCENES for c in SA.CIRCUITS}
    for e in decided:  # no method decides a scene before its farthest target is touched
        assert e["decision_time_s"] >= committed_sa["floors"][f"{e['scene']} {e['circuit']}"]["contact_s"], e
    # on the slow circuit nothing is known before contact: t_c methods have not decided at 0.1 s
    slow = [r for r in committed_sa["rows"] if r["scene"] == "gripper-cylinder" and r["circuit"] == "slow"
            and r["decision_time_s"] == 0.1 and r["method"] in ("t_c_threshold", "early")]
    assert all(r["decided_fraction"] < 0.05 for r in slow)


def test_the_grid_resolves_each_earliest_decision_as_a_ratio_to_its_floor(committed_sa):
    """Between the farthest contact and twice the settled time, no two decision times are
    further apart than FINE_STEP_OF_FLOOR of the floor, for every scene and circuit; the
    README states each earliest decision as that ratio."""
    from lab.bench import _speed_chart as chart

    rows, first = committed_sa["rows"], SA.earliest(committed_sa["rows"], committed_sa["trials"])
    readme = (REPO / "docs" / "speed-accuracy" / "README.md").read_text()
    for scene in SA.SCENES:
        for circuit in SA.CIRCUITS:
            fl = committed_sa["floors"][f"{scene} {circuit}"]
            times = SA.times_of(rows, scene, circuit)
            step = SA.FINE_STEP_OF_FLOOR * fl["settled_s"] + 1.5e-3  # (the step is rounded to the ms)
            near = [t for t in times if fl["contact_s"] <= t <= min(SA.FINE_UP_TO_FLOORS * fl["settled_s"], 5.0)]
            assert 5.0 in times and near[0] - fl["contact_s"] <= step, (scene, circuit, near[0])
            gaps = [b - a for a, b in zip(near, near[1:])]
            assert max(gaps) <= step, (scene, circuit, max(gaps))
            best = chart.best_ratio(first, scene, circuit, fl)
            if best is not None:
                assert f"x{best:.2f}" in readme
    assert chart.headline(committed_sa) in readme


def test_the_same_as_tolerance_is_the_sampling_error_of_a_95th_percentile():
    rng = np.random.default_rng(3)
    p95 = np.percentile(np.abs(rng.normal(size=(4000, 200))), 95, axis=1)
    diff = (p95[:2000] - p95[2000:]) / 1.96
    assert SA.same_as(200) == pytest.approx(diff.std(), rel=0.1)


@pytest.fixture(scope="module")
def committed_st():
    return json.loads((REPO / "docs" / "stability" / "results.json").read_text())


def _row(rows, part, pert, strength, subject):
    return next(r for r in rows if r["part"] == part and r["perturbation"] == pert and r["strength"] == strength
                and r["subject"] == subject)


def test_misalignment_breaks_first_rise_t_c_not_the_threshold_variant(committed_st):
    rows = ST.size_part("off-centre", committed_st["trials"], committed_st["seed"])
    first_10, thr_10 = (_row(rows, "size", "off-centre", 10.0, s) for s in ("t_c first rise", "t_c at dP threshold"))
    assert first_10["value"] > 3 * ST.SIZE_THRESHOLD_MM  # the early push of one finger fools the first rise
    assert thr_10["value"] <= ST.SIZE_THRESHOLD_MM  # the threshold variant waits for the real grip
    assert thr_10["decided_fraction"] >= 0.9  # (the smallest cylinders may not reach the threshold)
    assert _row(rows, "size", "off-centre", 0.0, "t_c first rise")["pass"]
    for r in rows:  # and the committed numbers are what the benchmark produces
        c = _row(committed_st["rows"], "size", "off-centre", r["strength"], r["subject"])
        assert _close(rounded(r["value"]), c["value"]) and r["pass"] == c["pass"]


def test_a_fresh_reference_survives_warm_tank_air():
    rows = ST.size_part("temperature", 8, ST.SEED)  # 8 held-out trials (the bench: 30)
    assert not _row(rows, "size", "temperature", 3.0, "p_eq")["pass"]
    assert not _row(rows, "size", "temperature", 3.0, "dp_eq, stale reference")["pass"]
    assert _row(rows, "size", "temperature", 3.0, "dp_eq, fresh reference")["pass"]


def test_off_centre_tomatoes_fool_the_first_rise_not_the_threshold():
    """The paper's ripeness finding, computed (one round instead of the bench's five): with
    tomatoes 10 mm off-centre, D0 from the first rise of dP is fooled by one finger's early
    push, D0 at a dP threshold is not."""
    task, cell = ST._task("ripeness")
    rates = {}
    for d0 in ("t_c_onset", "t_c_threshold"):
        t = task.model_copy(update={"misalignment_mm": 10.0, "d0_from": d0, "shuffle_seed": ST.SEED, "rounds": 1,
                                    "calibration_grips": 3})
        summary, why = ST._attempt(t, cell)
        assert summary is not None, (d0, why)
        rates[d0] = summary["success_rate"]
    assert rates["t_c_onset"] < ST.TASK_THRESHOLD <= rates["t_c_threshold"], rates
