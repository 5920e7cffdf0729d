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
