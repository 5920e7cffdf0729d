"""Sensing features: pure functions on numpy arrays (SI units, time in s).

Paper references: per-cycle offset (Methods, retrofit sections: mean of the last 0.5-1 s
before the valve opens); window mean over [t0, t1] after opening (Methods, size
sensing); dP against a free-air reference and the time of first contact (Methods,
"Time of first contact"); dP_max and t_c at a dP threshold (ripeness experiment);
smoothing by local quadratic regression over 20 samples (Methods, distance sensing).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import math

import numpy as np


@dataclass(frozen=True)
class WindowStats:
    mean: float
    sd: float
    n: int


@lru_cache(maxsize=16)
def _quadratic_fit_rows(span: int) -> np.ndarray:
    """Least-squares quadratic over ``span`` points: row k gives the fitted value at point k."""
    x = np.arange(span, dtype=float) - span // 2
    design = np.vander(x, 3, increasing=True)
    return design @ np.linalg.pinv(design)


def smooth(x: np.ndarray, span: int = 21) -> np.ndarray:
    """Local quadratic regression over ``span`` samples (Savitzky-Golay, polyorder 2).

    The paper used MATLAB's loess with a 20-point span; Savitzky-Golay is the same local
    quadratic least-squares fit without loess's tricube weights, on an odd span. This is
    scipy.signal.savgol_filter(x, span, 2, mode="interp") (tests/unit/test_features.py holds
    the two equal): written out because importing scipy.signal costs every daemon and CLI
    start about 0.7 s of CPU (docs/architecture.md, "The test suite").
    """
    x = np.asarray(x, dtype=float)
    span = int(span) | 1  # odd
    if len(x) < span:
        return x.copy()
    rows, half = _quadratic_fit_rows(span), span // 2
    out = np.convolve(x, rows[half][::-1], mode="same")
    # the first and last half-spans: the quadratic through the first (last) span, read there
    out[:half] = rows[:half] @ x[:span]
    out[-half:] = rows[span - half:] @ x[-span:]
    return out


def _between(t: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return (t >= lo) & (t < hi)


def sensor_offset(t: np.ndarray, p: np.ndarray, t_open: float, duration_s: float) -> float:
    """Mean reading over the last ``duration_s`` before the actuation valve opens.

    The actuator is vented then, so whatever the sensor reads is its offset.
    """
    sel = _between(t, t_open - duration_s, t_open)
    if not sel.any():
        raise ValueError(f"no samples in the {duration_s} s before t_open={t_open}")
    return float(np.mean(p[sel]))


def drift(t: np.ndarray, p: np.ndarray) -> tuple[float, float]:
    """Change of ``p`` over the span of ``t`` by a least-squares line, and its standard
    error from the scatter about that line: is the vented actuator still moving?"""
    n = len(t)
    if n < 3:
        return float("nan"), float("inf")
    tc = t - t.mean()
    sxx = float(np.sum(tc * tc))
    if sxx <= 0:
        return float("nan"), float("inf")
    slope = float(np.sum(tc * (p - p.mean())) / sxx)
    resid = p - p.mean() - slope * tc
    se_slope = float(np.sqrt(np.sum(resid * resid) / (n - 2) / sxx))
    span = float(t[-1] - t[0])
    return slope * span, se_slope * span


def window_stats(t: np.ndarray, p: np.ndarray, t_open: float, start_s: float, end_s: float) -> WindowStats:
    """Mean and sample sd of ``p`` over [t_open + start_s, t_open + end_s)."""
    sel = _between(t, t_open + start_s, t_open + end_s)
    n = int(sel.sum())
    if n == 0:
        raise ValueError(f"no samples in window [{start_s}, {end_s}) s after opening")
    vals = p[sel]
    return WindowStats(float(np.mean(vals)), float(np.std(vals, ddof=1)) if n > 1 else 0.0, n)


def integrate(t: np.ndarray, q: np.ndarray, t0: float, t1: float) -> float:
    """Integral of ``q`` over [t0, t1) (trapezoids between the samples inside)."""
    sel = _between(t, t0, t1)
    if sel.sum() < 2:
        raise ValueError(f"fewer than two samples in [{t0}, {t1})")
    return float(np.trapezoid(q[sel], t[sel]))


def delta_p(t_rel: np.ndarray, p: np.ndarray, ref_t_rel: np.ndarray, ref_p: np.ndarray) -> np.ndarray:
    """dP = P - P_ref, the reference interpolated onto ``t_rel`` (time since opening).

    Outside the reference's time span dP is NaN: nothing is extrapolated.
    """
    ref = np.interp(t_rel, ref_t_rel, ref_p, left=np.nan, right=np.nan)
    return np.asarray(p, dtype=float) - ref


def crossing_time(t: np.ndarray, y: np.ndarray, level: float) -> float | None:
    """First time ``y`` reaches ``level`` from below (linear interpolation between samples;
    NaN samples never reach it). None if it never does."""
    above = np.isfinite(y) & (y >= level)
    if not above.any():
        return None
    k = int(np.argmax(above))
    if k == 0:
        return float(t[0])
    t0, t1, y0, y1 = t[k - 1], t[k], y[k - 1], y[k]
    if not np.isfinite(y0) or y1 == y0:
        return float(t1)
    return float(t0 + (level - y0) * (t1 - t0) / (y1 - y0))


def sample_period(t: np.ndarray) -> float:
    """The samples' nominal spacing: the median over the first thousand (a busy PC's missed
    slots are gaps, not the period)."""
    return float(np.median(np.diff(t[: min(len(t), 1000)])))


def _bracketed(t: np.ndarray, y: np.ndarray, level: float, max_gap: float) -> float | None:
    """crossing_time, or NaN where the two samples around the crossing are more than
    ``max_gap`` apart: across a gap (a busy PC's missed slots) the interpolated time is a
    guess, and on a steep rise a ms of guess is tenths of a kPa of dP. None: never reached.
    Samples that repeat the one before exactly are not taken as their slot's value: a
    polled box that did not refresh its register in time answers a read with the older
    value, which on a rise reads as a rise that came later (through the emulated box, a run
    of them put a whole rise 2-5 ms late); the crossing is bracketed from the first of the
    run, so a run that long is a gap."""
    above = np.isfinite(y) & (y >= level)
    if not above.any():
        return None
    k = int(np.argmax(above))
    if k == 0:
        return math.nan
    j = k - 1
    while j > 0 and y[j] == y[j - 1]:
        j -= 1
    if t[k] - t[j] > max_gap:
        return math.nan
    return crossing_time(np.array([t[j], t[k]]), np.array([y[j], y[k]]), level)


def rise_shift(t_rel: np.ndarray, p: np.ndarray, ref_t_rel: np.ndarray, ref_p: np.ndarray, lo: float, hi: float,
               levels: int = 5, min_levels: int = 3) -> float | None:
    """How much later than the reference's this cycle rose through ``lo..hi`` (both oriented
    so that the rise is upwards, offsets removed): the median over ``levels`` levels of the
    difference of crossing times. A level whose crossing falls in a gap of either curve
    (samples more than 2.5 periods apart) is left out. None when either curve does not
    reach ``hi``, or fewer than ``min_levels`` levels are left, or fewer than
    ``min_levels`` of them agree with the median within one sample period: then some
    samples on the rise were not read when their slot says (a polled box that refreshed
    late answers a read with an older value), and no one shift fits the curve."""
    if len(t_rel) < 2 or len(ref_t_rel) < 2:
        return None
    period = sample_period(t_rel)
    gap, ref_gap = 2.5 * period, 2.5 * sample_period(ref_t_rel)
    shifts = []
    for level in np.linspace(lo, hi, levels):
        t_meas, t_ref = _bracketed(t_rel, p, level, gap), _bracketed(ref_t_rel, ref_p, level, ref_gap)
        if t_meas is None or t_ref is None:
            return None
        if not (math.isnan(t_meas) or math.isnan(t_ref)):
            shifts.append(t_meas - t_ref)
    if len(shifts) < min_levels:
        return None
    middle = float(np.median(shifts))
    agree = [s for s in shifts if abs(s - middle) <= period]
    return float(np.median(agree)) if len(agree) >= min_levels else None


def contact_time_threshold(t_rel: np.ndarray, dp: np.ndarray, threshold: float) -> float | None:
    """First time dP reaches ``threshold`` (linear interpolation between samples).

    ``dp`` should already be smoothed. None if it never does.
    """
    return crossing_time(t_rel, dp, threshold)


def dp_max(t_rel: np.ndarray, dp: np.ndarray) -> tuple[float, float] | None:
    """Largest dP and when it happens (use a smoothed dP)."""
    ok = np.isfinite(dp)
    if not ok.any():
        return None
    k = int(np.nanargmax(np.where(ok, dp, -np.inf)))
    return float(dp[k]), float(t_rel[k])


def _hinge_sse(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """SSE of the best fit of ``a + b*u + c*u**2``, ``u = max(0, t - t[k])``, for every k.

    Built from suffix power sums so that all splits cost O(n) together.
    """
    n = len(t)
    span = t[-1] - t[0] or 1.0
    x = (t - t[0]) / span  # scaled to [0, 1] for a well-conditioned normal matrix
    rev = slice(None, None, -1)
    s = [np.cumsum(x[rev] ** j)[rev] for j in range(5)]  # s[j][k] = sum_{i>=k} x_i^j
    yy = [np.cumsum((y * x**j)[rev])[rev] for j in range(3)]
    c = x  # candidate split at x[k]
    su1 = s[1] - c * s[0]
    su2 = s[2] - 2 * c * s[1] + c**2 * s[0]
    su3 = s[3] - 3 * c * s[2] + 3 * c**2 * s[1] - c**3 * s[0]
    su4 = s[4] - 4 * c * s[3] + 6 * c**2 * s[2] - 4 * c**3 * s[1] + c**4 * s[0]
    syu1 = yy[1] - c * yy[0]
    syu2 = yy[2] - 2 * c * yy[1] + c**2 * yy[0]
    sy = np.full(n, y.sum())
    m = np.empty((n, 3, 3))
    m[:, 0] = np.column_stack([np.full(n, float(n)), su1, su2])
    m[:, 1] = np.column_stack([su1, su2, su3])
    m[:, 2] = np.column_stack([su2, su3, su4])
    rhs = np.column_stack([sy, syu1, syu2])
    sse = np.full(n, np.inf)
    ok = np.abs(np.linalg.det(m)) > 1e-12 * np.abs(m).max(axis=(1, 2)) ** 3
    coef = np.linalg.solve(m[ok], rhs[ok][..., None])[..., 0]
    sse[ok] = float(np.sum(y * y)) - np.einsum("ij,ij->i", coef, rhs[ok])
    return sse


def contact_time_slope(t_rel: np.ndarray, dp: np.ndarray, min_rise: float) -> float | None:
    """Time of first contact as the abrupt change of slope of dP (use a smoothed dP).

    dP is flat before contact and bends upwards at it, so a hinge is fitted: constant up
    to t_c, then a quadratic in (t - t_c), continuous at t_c. The t_c with the least
    squared error over [opening, first time dP reaches half its maximum] is the change
    point. (The paper detected "abrupt changes in slope" with a MATLAB script; a
    straight line after the kink, as in ``findchangepts``, sits 5-10 ms late on the
    concave rise, this hinge does not.) Returns None when dP never rises by
    ``min_rise``: no contact, nothing to find.
    """
    ok = np.isfinite(dp) & (t_rel >= 0)
    t, y = t_rel[ok], dp[ok]
    if len(t) < 8:
        return None
    peak = float(np.max(y))
    # both traces start from the same vented actuator, so dP starts near zero
    if peak - float(np.median(y[:10])) < min_rise:
        return None
    k_half = int(np.argmax(y >= 0.5 * peak))
    if k_half < 6:
        return None
    t, y = t[: k_half + 1], y[: k_half + 1]
    sse = _hinge_sse(t, y)
    sse[:2] = np.inf  # keep at least two points before the split ...
    sse[-3:] = np.inf  # ... and three after it
    return float(t[int(np.argmin(sse))])


def second_contact_time(t_rel: np.ndarray, dp: np.ndarray, t_c1: float, min_rise: float,
                        min_jump: float = 0.2) -> float | None:
    """Time of a second contact after ``t_c1`` (use a smoothed dP).

    Between contacts dP rises and bends over smoothly; a second contact (another finger
    pair meeting the object) puts a kink into it: the slope jumps up. From t_c1 until dP
    reaches 95 % of its maximum, a quadratic plus a hinge ``d*max(0, t - t2)`` is fitted for
    every candidate t2 (on every 10th sample: the kink spans many samples anyway); the best
    t2 counts as a contact when the slope jumps by at least ``min_jump`` of the slope just
    before it and dP still rises by ``min_rise`` afterwards. None otherwise.
    """
    ok = np.isfinite(dp) & (t_rel > t_c1)
    t, y = t_rel[ok][::10], dp[ok][::10]
    if len(t) < 10:
        return None
    k_end = int(np.argmax(y >= 0.95 * np.max(y)))
    t, y = t[: k_end + 1], y[: k_end + 1]
    n = len(t)
    if n < 10:
        return None
    x = (t - t[0]) / (t[-1] - t[0])
    base = np.column_stack([np.ones(n), x, x * x])
    best_sse, best_k, best_coef = np.inf, -1, None
    for k in range(3, n - 3):
        design = np.column_stack([base, np.clip(x - x[k], 0.0, None)])
        coef, *_ = np.linalg.lstsq(design, y, rcond=None)
        sse = float(np.sum((design @ coef - y) ** 2))
        if sse < best_sse:
            best_sse, best_k, best_coef = sse, k, coef
    if best_coef is None:
        return None
    slope_before = best_coef[1] + 2 * best_coef[2] * x[best_k]
    if slope_before <= 0 or best_coef[3] < min_jump * slope_before or y[-1] - y[best_k] < min_rise:
        return None
    return float(t[best_k])


class EarlyEstimate:
    """Equilibrium predicted from the transient, or the reason it cannot be yet."""

    __slots__ = ("p_inf", "sd", "tau", "t_contact", "reason")

    def __init__(self, p_inf: float | None, sd: float | None, tau: float | None, t_contact: float | None,
                 reason: str | None = None):
        self.p_inf, self.sd, self.tau, self.t_contact, self.reason = p_inf, sd, tau, t_contact, reason

    @property
    def ready(self) -> bool:
        return self.p_inf is not None

    def __repr__(self) -> str:  # pragma: no cover - debugging aid
        return f"EarlyEstimate(p_inf={self.p_inf}, sd={self.sd}, tau={self.tau}, reason={self.reason})"


def early_equilibrium(t_rel: np.ndarray, p: np.ndarray, t_contact: float | None, t_decision: float,
                      min_after_s: float = 0.01, max_sd: float | None = None) -> EarlyEstimate:
    """Predict the equilibrium pressure from the transient up to ``t_decision``.

    After contact, tank, resistor and actuator form a first-order circuit (one resistor
    between two capacities, the total gas fixed), so the pressure approaches its
    equilibrium as ``P_inf - A*exp(-(t - t_c)/tau)``. That is fitted to the samples from
    contact to the decision time; the sd of P_inf comes from the fit's covariance. Before
    contact there is nothing to say ("not yet": the free actuator carries no information
    about the object); so too with fewer than ``min_after_s`` of data after contact, or
    when the sd exceeds ``max_sd``.
    """
    from scipy.optimize import curve_fit

    if t_contact is None or t_contact >= t_decision:
        return EarlyEstimate(None, None, None, t_contact, "no contact yet")
    sel = (t_rel >= t_contact) & (t_rel <= t_decision)
    t, y = t_rel[sel] - t_contact, p[sel]
    if len(t) < 8 or t[-1] < min_after_s:
        return EarlyEstimate(None, None, None, t_contact, "too little data after contact")
    span = t[-1]
    slope_end = np.polyfit(t[-min(len(t), 20):], y[-min(len(t), 20):], 1)[0]
    tau0 = max(span / 3, 1e-3)
    guess = [y[-1] + slope_end * tau0, max(abs(y[-1] - y[0]), 1.0), tau0]

    def model(x, p_inf, a, tau):
        return p_inf - a * np.exp(-x / tau)

    try:
        (p_inf, a, tau), cov = curve_fit(model, t, y, p0=guess, bounds=([-np.inf, -np.inf, 1e-4], [np.inf, np.inf, 100.0]),
                                         maxfev=2000)
    except (RuntimeError, ValueError):
        return EarlyEstimate(None, None, None, t_contact, "fit did not converge")
    sd = float(np.sqrt(cov[0, 0])) if np.isfinite(cov[0, 0]) else float("inf")
    if not np.isfinite(sd) or (max_sd is not None and sd > max_sd):
        return EarlyEstimate(None, sd, float(tau), t_contact, "interval still too wide")
    return EarlyEstimate(float(p_inf), sd, float(tau), t_contact)
