"""Calibration: fitting, inverting with an interval, files, and the accuracy it reaches.

(Its tests with real peers: tests/system/test_calibration.py.)
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from fluidsense.common.errors import ConfigError
from fluidsense.controller.sensing.calibration import Calibration, CalibrationError


def synthetic(slope=-0.04, sd=0.03, n_per=7, seed=0, fit="linear", curve=0.0):
    rng = np.random.default_rng(seed)
    x = np.repeat(np.arange(0, 45, 5.0), n_per)
    y = 22.6 + slope * x + curve * x**2 + rng.normal(0, sd, len(x))
    meta = dict(profile="p", method="tank", feature="p_eq", feature_unit="kPa", scene={"kind": "plate"},
                target="height_mm", target_unit="mm")
    return Calibration.fit_points(x, y, fit, **meta)


def test_inverse_of_a_noiseless_line_is_exact():
    cal = synthetic(sd=1e-9)
    est = cal.invert(22.6 - 0.04 * 17.5)
    assert est.estimate == pytest.approx(17.5, abs=1e-6)
    assert not est.extrapolated and est.unit == "mm"


def test_interval_covers_the_truth_about_95_percent_of_the_time():
    """Over many calibrations (the interval also accounts for the curve's own error)."""
    rng = np.random.default_rng(2)
    inside = total = 0
    for seed in range(300):
        cal = synthetic(sd=0.03, seed=100 + seed)
        truth = rng.uniform(0, 40, 10)
        measured = 22.6 - 0.04 * truth + rng.normal(0, 0.03, len(truth))
        for h, y in zip(truth, measured):
            lo, hi = cal.invert(y).interval95
            inside += lo <= h <= hi
            total += 1
    assert inside / total == pytest.approx(0.95, abs=0.015)
    # half width is about t * sd / slope: 0.03 / 0.04 * 1.99 = 1.5 mm
    lo, hi = synthetic(sd=0.03, seed=1).invert(22.6 - 0.04 * 20).interval95
    assert (hi - lo) / 2 == pytest.approx(1.99 * 0.03 / 0.04, rel=0.15)


def test_averaging_cycles_narrows_the_interval():
    cal = synthetic()
    one = cal.invert(21.8)
    four = cal.invert(21.8, n_measurements=4)
    assert four.interval95[1] - four.interval95[0] < 0.6 * (one.interval95[1] - one.interval95[0])


def test_polynomial_fit_follows_a_curve():
    cal_lin = synthetic(curve=0.001, sd=0.005)
    cal_q = synthetic(curve=0.001, sd=0.005, fit="poly2")
    assert cal_q.residual_sd < 0.5 * cal_lin.residual_sd
    y = 22.6 - 0.04 * 30 + 0.001 * 900
    assert cal_q.invert(y).estimate == pytest.approx(30, abs=0.3)


def test_outside_what_the_curve_predicts_is_an_error():
    cal = synthetic()
    with pytest.raises(CalibrationError, match="outside"):
        cal.invert(40.0)
    with pytest.raises(CalibrationError, match="distinct targets"):
        Calibration.fit_points([1, 1, 1], [2, 3, 4], "linear", profile="p", method="tank", feature="p_eq",
                               feature_unit="kPa", scene={}, target="x", target_unit="mm")


def test_file_round_trip_and_bad_files(tmp_path):
    cal = dataclasses.replace(synthetic(), session_rel_sd=0.005)
    path = tmp_path / "cal.json"
    cal.save(path)
    again = Calibration.load(path)
    assert again == cal
    data = json.loads(path.read_text())
    assert data["format"] == "fluidsense-calibration/1"
    del data["session_rel_sd"]  # a file written before the session term: read as none
    (tmp_path / "old.json").write_text(json.dumps(data))
    assert Calibration.load(tmp_path / "old.json").session_rel_sd == 0.0
    (tmp_path / "bad.json").write_text("{\"format\": \"other\"}")
    with pytest.raises(ConfigError, match="not a calibration file"):
        Calibration.load(tmp_path / "bad.json")
    with pytest.raises(ConfigError, match="cannot read"):
        Calibration.load(tmp_path / "missing.json")


# ----------------------------------------------------------- estimates: what a reading says
def _with_free(cal, level=23.6, sd=0.03, n=7, seed=5):
    cal.free_y = list(level + np.random.default_rng(seed).normal(0, sd, n))
    return cal


def test_estimate_is_si_with_an_interval_and_status_ok():
    cal = _with_free(synthetic())
    est = cal.estimate((22.6 - 0.04 * 17.5) * 1e3)  # Pa in
    assert est.status == "ok" and est.quantity == "height" and est.unit == "m"
    assert est.value == pytest.approx(17.5e-3, abs=1e-3) and est.lo < est.value < est.hi
    assert set(est.as_dict()) >= {"quantity", "value", "lo", "hi", "coverage", "status"}
    assert est.to_edge("mm")["value_mm"] == pytest.approx(est.value * 1e3)


def test_the_free_reading_is_no_object_and_beyond_the_range_is_out_of_range():
    cal = _with_free(synthetic())  # P_eq falls with h; nothing there reads 23.6 kPa (above h = 0)
    empty = cal.estimate(23.6e3)
    assert empty.status == "no_object" and empty.value is None and "free reading" in empty.detail
    assert cal.estimate(None).status == "no_object"  # no contact feature at all
    far = cal.estimate((22.6 - 0.04 * 55) * 1e3)  # h = 55 mm: calibrated 0..40
    assert far.status == "out_of_range" and far.bound == pytest.approx(40e-3) and far.lo == far.bound
    assert far.value is None and far.hi is None
    # just inside the range stays a value, even when the free level is known
    assert cal.estimate((22.6 - 0.04 * 39) * 1e3).status == "ok"
    # just outside it, with an interval that still reaches into it, is not a size: the
    # calibration says nothing beyond its targets
    for h, bound in ((40.5, 40e-3), (-0.5, 0.0)):
        edge = cal.estimate((22.6 - 0.04 * h) * 1e3)
        a, b = cal.invert(22.6 - 0.04 * h).interval95
        assert (a < max(cal.x)) if h > 20 else (b > min(cal.x))  # the interval reaches into the range
        assert edge.status == "out_of_range" and edge.value is None and edge.bound == pytest.approx(bound), h


def test_no_object_moves_with_the_session_term():
    """A later set-up moves the free level as it moves every reading: a reading 0.5 kPa off
    a free level of 23.6 kPa (free cycles' sd 0.03) is an object for a curve used in its own
    session, within the free noise for one whose set-ups differ by 1 % (sd)."""
    cal = _with_free(synthetic())
    moved = dataclasses.replace(cal, session_rel_sd=0.01)
    level = float(np.mean(cal.free_y))
    assert cal.free_reading(level - 0.5, 1) is None
    assert moved.free_reading(level - 0.5, 1) is not None
    assert moved.free_reading(level - 1.5, 1) is None  # 3 x sqrt(2) x 1 % x 23.6 = 1.0 kPa


def test_lack_of_fit_does_not_average_away():
    """A curved truth fitted by a line: the interval of a 50-cycle mean keeps the lack of
    fit, so it covers the truth at every calibrated height; pure error alone would not."""
    cal = synthetic(curve=0.0006, sd=0.01, n_per=7, seed=3)
    covered = 0
    for h in np.arange(0, 45, 5.0):
        y = 22.6 - 0.04 * h + 0.0006 * h**2
        inv = cal.invert(y, n_measurements=50)
        covered += inv.interval95[0] <= h <= inv.interval95[1]
    assert covered == 9
