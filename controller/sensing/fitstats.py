"""The uncertainty of a calibration curve, split by where it comes from.

A calibration repeats cycles at each target, so its residuals separate into
- pure error: the scatter of cycles at one target (sensor noise in the window, the
  offset's noise, the regulator's cycle-to-cycle error). Averaging m sensing cycles
  divides its variance by m;
- lack of fit: how far the target means sit from the curve (the curve is not the exact
  law). It is the same for every cycle at a target, so averaging does not shrink it;
- the curve's own error: its coefficients come from a finite number of cycles
  (the leverage of the point where the curve is read).

The interval of an inverse prediction adds the three variances and divides by the local
slope (classical calibration, inverse prediction).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FitStats:
    pure_sd: float  # within-target sd (one cycle)
    lof_sd: float  # sd of a target mean about the curve beyond pure error
    resid_sd: float  # total residual sd of the fit
    dof: int  # residual degrees of freedom
    xtx_inv: np.ndarray  # (X^T X)^-1 of the polynomial design, highest power first


def fit_stats(x, y, coeffs) -> FitStats:
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    deg = len(coeffs) - 1
    p = deg + 1
    resid = y - np.polyval(coeffs, x)
    dof = len(x) - p
    resid_sd = float(np.sqrt(np.sum(resid**2) / dof)) if dof > 0 else 0.0
    targets, inverse, counts = np.unique(x, return_inverse=True, return_counts=True)
    means = np.bincount(inverse, weights=y) / counts
    ss_pure = float(np.sum((y - means[inverse]) ** 2))
    dof_pure = len(x) - len(targets)
    if dof_pure <= 0:  # no repeats: the residual cannot be split
        pure_sd, lof_sd = resid_sd, 0.0
    else:
        pure_sd = math.sqrt(ss_pure / dof_pure)
        dof_lof = len(targets) - p
        lof_sd = 0.0
        if dof_lof > 0:
            ss_lof = float(np.sum(counts * (means - np.polyval(coeffs, targets)) ** 2))
            ms_lof = ss_lof / dof_lof
            lof_sd = math.sqrt(max(0.0, (ms_lof - pure_sd**2) / float(np.mean(counts))))
    design = np.vander(x, p)
    xtx_inv = np.linalg.pinv(design.T @ design)
    return FitStats(pure_sd, lof_sd, resid_sd, dof, xtx_inv)


def prediction_sd(fs: FitStats, x0: float, n_measurements: int = 1) -> float:
    """sd of (measured mean of ``n_measurements`` cycles - curve) at target ``x0``, in
    feature units."""
    v = np.vander([x0], fs.xtx_inv.shape[0])[0]
    lever = float(v @ fs.xtx_inv @ v)
    var = fs.pure_sd**2 / max(n_measurements, 1) + fs.lof_sd**2 + fs.resid_sd**2 * max(lever, 0.0)
    return math.sqrt(var)


def load_quantiles() -> None:
    """Import what ``t_quantile`` needs, now: called where a calibration is loaded (before
    any loop runs), so that a daemon's first interval does not import scipy.special in its
    sample loop (0.2-0.35 s of CPU quiet, more than a second beside busy processes: a
    fresh daemon's first grasp once latched ``overrun``; docs/performance.md, "The overrun
    as load starts")."""
    from scipy import special  # noqa: F401, PLC0415


def t_quantile(coverage: float, dof: int) -> float:
    """Two-sided quantile of Student's t for ``coverage`` (normal when dof is unknown)."""
    # scipy.stats' t.ppf and norm.ppf are these functions; scipy.special imports in a third
    # of the time. Imported here, not with the module: the daemon imports this module at
    # start (every daemon, simcell and CLI start in the suite paid 0.2-0.35 s of CPU for
    # it) and most of them never compute an interval; those that load a calibration import
    # it then (load_quantiles).
    from scipy import special

    q = 0.5 + coverage / 2
    return float(special.stdtrit(dof, q)) if dof > 0 else float(special.ndtri(q))
