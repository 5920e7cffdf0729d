"""The gripper in this process: the slip watch on recorded block means (a stream that stalls
included), and a calibration of another profile refused before the daemon starts. (The
daemon as a gripper over real sockets, driven through the client library:
tests/system/test_gripper.py.)"""

from __future__ import annotations

import numpy as np
import pytest
from fluidsense.controller.requests.grip_watch import SlipWatch
from support.cli import run_cli
from support.harness import REPO, sim_config

CALIBRATION = REPO / "config" / "calibrations" / "pneunet-gripper-p_eq.json"


def gripper_config(tmp_path, calibrated: bool = True, **gripper):
    return sim_config(tmp_path, clock="virtual",
                      gripper={"calibrations": [str(CALIBRATION)] if calibrated else [], **gripper})


def _slip_blocks(tau_s: float, stall_s: float, seed: int):
    """Block means (t, Pa) of a held grip that slips at t = 1 s, shaped as the simulated
    pneunet gripper's recording of the 60 -> 40 mm slip (held 36.62 kPa, a dip to 34.85,
    back to 35.78 with a time constant ``tau_s``, about 0.12 s there), 10 ms blocks with
    the sensor's noise. ``stall_s``: the stream stalls 30 ms after the slip and its backlog
    arrives that much later (as ur_rtde's receive thread starved on a busy PC)."""
    rng = np.random.default_rng(seed)
    held, dip, settled = 36.62e3, 34.85e3, 35.78e3
    t = np.arange(0.0, 3.0, 0.01)
    p = np.where(t < 1.0, held, settled - (settled - dip) * np.exp(-(t - 1.0) / tau_s))
    p = p + rng.normal(0, 30.0, t.size)  # a 10-sample mean of 0.1 kPa noise
    stamped = np.where(t < 1.03, t, t + stall_s)
    return list(zip(stamped, p)), settled


@pytest.mark.parametrize("tau_s, stall_s", [(0.12, 0.0), (0.12, 0.3), (0.3, 0.3)])
def test_a_slip_is_reported_at_the_level_it_settles_at_even_across_a_stalled_stream(tau_s, stall_s):
    """The slip's level gives the new size (0.04 kPa per mm on the shipped calibration):
    it must be the settled level, not the bottom of the dip. Two faults of the first
    version: with the sensor's noise its 'steady' (the range of the block means below a
    third of the drop) was rarely true, so a slip waited for the 5 s fallback; and across
    a stall, the dip's samples arriving late made a flat stretch of the gap, and the slip
    was reported at the dip (a size below the calibrated range, seen in CI through the ur
    driver; 0.8 kPa low here with the slower recovery)."""
    for seed in range(10):  # the noise decides when a flat stretch shows: ten draws of it
        blocks, settled = _slip_blocks(tau_s, stall_s, seed)
        watch = SlipWatch(drop_pa=300.0, within_s=0.5, sign=1.0, level_pa=36.62e3)
        reports = [(t, r) for t, p in blocks if (r := watch.feed(t, p)) is not None]
        assert len(reports) == 1, (seed, reports)
        ((reported_at, slip),) = reports
        assert slip["at_s"] == pytest.approx(1.0, abs=0.03), seed
        assert reported_at < 1.0 + stall_s + 1.5, seed  # settled, not the 10 x within_s fallback
        assert slip["level_pa"] == pytest.approx(settled, abs=60.0), seed  # 1.5 mm
        assert slip["drop_pa"] == pytest.approx(36.62e3 - settled, abs=60.0), seed


def test_a_calibration_of_another_profile_stops_the_daemon_before_it_starts(tmp_path, capsys):
    import json

    other = json.loads(CALIBRATION.read_text()) | {"profile": "sorting-gripper"}
    (tmp_path / "other.json").write_text(json.dumps(other))
    path = gripper_config(tmp_path, calibrations=["other.json"])  # relative to the cell config
    out = run_cli(capsys, "run", "--config", path, cwd=REPO)  # started, it would bind: the unit tier's guard
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert f"{path}: gripper.calibrations.0: " in out.stderr and "calibrates profile 'sorting-gripper'" in out.stderr
