"""Features on analytic signals with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from fluidsense.controller.cycles import features as F

FS = 1000.0


def timebase(t0: float, t1: float) -> np.ndarray:
    return np.arange(int(round(t0 * FS)), int(round(t1 * FS))) / FS


def test_smoothing_keeps_a_quadratic_and_cuts_white_noise():
    t = timebase(0, 2)
    quad = 3.0 + 2.0 * t - 1.5 * t**2
    np.testing.assert_allclose(F.smooth(quad, 21), quad, atol=1e-9)
    rng = np.random.default_rng(0)
    noise = rng.normal(0, 1.0, 200_000)
    sd = np.std(F.smooth(noise, 21))
    # noise gain of a quadratic Savitzky-Golay filter over 2m+1 points is its central
    # coefficient, 3(3m^2+3m-1)/((2m-1)(2m+1)(2m+3)); 0.1075 for m = 10
    m = 10
    gain = 3 * (3 * m * m + 3 * m - 1) / ((2 * m - 1) * (2 * m + 1) * (2 * m + 3))
    assert sd == pytest.approx(np.sqrt(gain), rel=0.02)


@pytest.mark.parametrize("n, span", [(21, 21), (22, 21), (500, 3), (500, 21), (14_300, 41)])
def test_smoothing_is_scipys_savgol_filter_in_interp_mode(n, span):
    """features.smooth is written out only to spare every process scipy.signal's import."""
    from scipy.signal import savgol_filter

    x = np.cumsum(np.random.default_rng(n).normal(0, 100.0, n))
    expected = savgol_filter(x, span, 2, mode="interp")
    np.testing.assert_allclose(F.smooth(x, span), expected, rtol=0, atol=1e-12 * np.abs(expected).max())


def test_sensor_offset_is_the_mean_just_before_opening():
    t = timebase(0, 20)
    p = np.where(t < 19.0, 5.0, 0.25) + np.where(t >= 20.0, 100.0, 0.0)  # 0.25 in the last second
    p = np.where(t >= 19.5, p + 1e3 * (t >= 20.0), p)
    assert F.sensor_offset(t, p, t_open=20.0, duration_s=1.0) == pytest.approx(0.25)
    assert F.sensor_offset(t, p, t_open=20.0, duration_s=2.0) == pytest.approx((5.0 + 0.25) / 2)


def test_sensor_offset_without_samples_is_an_error():
    with pytest.raises(ValueError, match="no samples"):
        F.sensor_offset(timebase(0, 1), np.zeros(1000), t_open=5.0, duration_s=1.0)


def test_window_stats_of_a_ramp():
    t = timebase(0, 10)
    p = 2.0 * t
    ws = F.window_stats(t, p, t_open=2.0, start_s=4.0, end_s=5.0)
    assert ws.n == 1000
    assert ws.mean == pytest.approx(2.0 * (6.0 + 6.999) / 2)
    assert ws.sd == pytest.approx(2.0 * np.std(np.arange(1000) / FS, ddof=1))


def test_delta_p_against_a_reference_and_nothing_outside_it():
    t = timebase(0, 3)
    ref = 10.0 * (1 - np.exp(-t / 0.2))
    p = ref + np.where(t > 1.0, 0.5 * (t - 1.0), 0.0)
    dp = F.delta_p(t, p, t[: 2500], ref[: 2500])
    np.testing.assert_allclose(dp[:1000], 0.0, atol=1e-12)
    assert dp[2000] == pytest.approx(0.5 * (2.0 - 1.0))
    assert np.isnan(dp[2600])


def test_contact_time_by_threshold_interpolates_between_samples():
    t = timebase(0, 1)
    dp = np.maximum(0.0, 4.0 * (t - 0.3004))  # crosses 0.5 at 0.4254
    assert F.contact_time_threshold(t, dp, 0.5) == pytest.approx(0.4254, abs=1e-9)
    assert F.contact_time_threshold(t, dp, 50.0) is None


@pytest.mark.parametrize("t_contact", [0.05, 0.12, 0.3])
def test_contact_time_by_slope_change_finds_the_kink(t_contact):
    """dP flat until contact, then rising and saturating (the shape the plant gives)."""
    rng = np.random.default_rng(int(t_contact * 1000))
    t = timebase(0, 3)
    after = np.clip(t - t_contact, 0, None)
    clean = 3000.0 * (1 - np.exp(-after / 0.15))
    dp = F.smooth(clean + rng.normal(0, 100.0, len(t)), 21)
    tc = F.contact_time_slope(t, dp, min_rise=500.0)
    assert tc == pytest.approx(t_contact, abs=0.01)


def test_contact_time_by_slope_needs_a_rise():
    rng = np.random.default_rng(3)
    t = timebase(0, 3)
    dp = F.smooth(rng.normal(0, 100.0, len(t)), 21)
    assert F.contact_time_slope(t, dp, min_rise=500.0) is None


def test_dp_max_and_its_time():
    t = timebase(0, 5)
    dp = 4.0 * np.exp(-((t - 1.234) ** 2) / 0.1)
    peak, t_peak = F.dp_max(t, dp)
    assert peak == pytest.approx(4.0, rel=1e-6)
    assert t_peak == pytest.approx(1.234, abs=1e-3)
    assert F.dp_max(t, np.full(len(t), np.nan)) is None
