"""Sensing features taken at a decision time t_d after the valve opens.

Every feature here only uses samples up to t_d (it could be computed live at that
moment), so one recorded cycle yields the feature at every decision time. Calibrate and
sense at the same t_d.
"""

from __future__ import annotations

import numpy as np
from fluidsense.controller.cycles import features as F

METHODS = ("window", "early", "t_c_slope", "t_c_threshold", "dp_max")
WINDOW_S = 0.05  # the paper's shortest window (Fig. S actuation speed: 0.05 s)


def features_at(t_rel: np.ndarray, p: np.ndarray, ref_t: np.ndarray | None, ref_p: np.ndarray | None,
                t_decisions, contact_kpa: float = 0.5, sign: float = 1.0,
                smoothing: int = 21) -> dict[float, dict[str, float | None]]:
    """{t_d: {method: value or None}} for one cycle (pressures in Pa, times in s).

    window: mean over [t_d - 0.05 s, t_d]; early: the first-order prediction of the
    equilibrium (None before contact); t_c_slope / t_c_threshold: contact time from dP up
    to t_d; dp_max: largest dP up to t_d. The dP features need a free-air reference.
    """
    have_ref = ref_t is not None and ref_p is not None
    if have_ref:
        dp = F.delta_p(t_rel, p, ref_t, ref_p)
        dps = F.smooth(np.nan_to_num(dp, nan=0.0), smoothing)
        dps[~np.isfinite(dp)] = np.nan
        oriented = sign * dps
    out: dict[float, dict[str, float | None]] = {}
    threshold = contact_kpa * 1e3
    for td in t_decisions:
        row: dict[str, float | None] = dict.fromkeys(METHODS)
        win = (t_rel > td - WINDOW_S) & (t_rel <= td)
        if win.any():
            row["window"] = float(np.mean(p[win]))
        if have_ref:
            upto = t_rel <= td
            tt, yy = t_rel[upto], oriented[upto]
            tc = F.contact_time_threshold(tt, yy, threshold)
            row["t_c_threshold"] = tc
            row["t_c_slope"] = F.contact_time_slope(tt, yy, min_rise=threshold)
            peak = F.dp_max(tt, yy)
            row["dp_max"] = None if peak is None or peak[0] < threshold else sign * peak[0]
            est = F.early_equilibrium(t_rel, p, tc, td)
            row["early"] = est.p_inf
            row["early_sd"] = est.sd if est.ready else None
        out[float(td)] = row
    return out
