"""Speed against accuracy and stability: the committed figures are what the benchmarks
produce, and the findings they rest on hold in virtual time.

(Its tests with real peers: tests/system/test_speed_stability.py.)
"""

from __future__ import annotations

import numpy as np
import pytest
from fluidsense.controller.cycles import features as F


def test_early_estimator_says_not_yet_before_contact_and_predicts_after():
    t = np.arange(0, 2000) / 1000.0
    p_inf, tau, t_c = 36000.0, 0.08, 0.3
    p = np.where(t < t_c, 20000.0 * t / t_c, p_inf - (p_inf - 20000.0) * np.exp(-(t - t_c) / tau))
    p = p + np.random.default_rng(0).normal(0, 70.0, len(t))
    assert not F.early_equilibrium(t, p, None, 0.2).ready  # no contact detected: not yet
    assert not F.early_equilibrium(t, p, t_c, 0.25).ready  # the decision comes before contact
    est = F.early_equilibrium(t, p, t_c, t_c + 0.12)  # 1.5 time constants after contact
    assert est.ready and abs(est.p_inf - p_inf) < 4 * est.sd and est.sd < 100.0
    assert est.tau == pytest.approx(tau, rel=0.2)


def test_the_stability_report_says_which_cycles_were_refused_and_why():
    """A perturbation whose cycles the controller refuses (its charge check) is a row without
    a value, shown as refused with the reason, and a task run that ended in an error names
    it: `make stability` once stopped at the first refusal instead."""
    from lab.bench import stability_report as report
    from lab.bench.stability_spec import PERTURBATIONS, SIZE_METHODS

    why = "reference cycle failed: not charged: the tank reads 65.04 kPa, P0 is 63.00 kPa"
    rows = []
    for name, (unit, strengths, _) in PERTURBATIONS.items():
        for s in strengths:
            refused = name == "regulator error" and s == 2.0
            rows += [{"part": "size", "perturbation": name, "strength": s, "unit": unit, "subject": m,
                      "metric": "err95_mm", "value": None if refused else 2.0, "bias_mm": None,
                      "decided_fraction": 0.0 if refused else 1.0, "threshold": 5.0, "pass": not refused,
                      **({"refused": why} if refused else {})} for m in SIZE_METHODS]
    rows.append({"part": "sorting", "perturbation": "regulator error", "strength": 2.0, "unit": "kPa",
                 "subject": "sorting task", "metric": "success_rate", "value": 0.0, "threshold": 0.8, "pass": False,
                 "task_faults": 10, "failed": "grip cycle 1 failed: not charged"})
    text = report._markdown({"rows": rows, "seed": 1, "trials": 30, "size_threshold_mm": 5.0, "task_threshold": 0.8})
    table = text.split("### regulator error")[1].split("###")[0]
    assert table.count("| refused |") == len(SIZE_METHODS)
    assert f"Refused at 2 kPa, every cycle (no reading to score): {why}" in table
    assert "**FAIL** (10 run(s) ended in an error, the first: grip cycle 1 failed: not charged)" in text
    assert "regulator error 2 kPa: every cycle refused, so no method reads a wrong size" in text
