"""Jobs that a fault stops say so and keep what they did: tasks, calibration (with its
journal and --resume), sensing; and a real-cell calibration never reads a prompt that
nobody can answer.

(Its in-process tests: tests/unit/test_jobs.py.)
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from fluidsense.tasks.journal import journal_path
from support.configs import DELETE, cell_config, task_config
from support.harness import REPO, free_simcell


def test_a_task_run_stopped_by_a_fault_exits_4_with_the_partial_summary(tmp_path):
    """Through a production driver, as a user runs it: the box's sensor freezes mid-task."""
    with free_simcell(tmp_path, "modbus", profile="sorting-gripper-quick.yaml", driver={"watchdog": None}) as (box, cell):
        task_file = task_config(tmp_path, "sorting", cell=str(cell),
                                motion={"speed_m_s": 1.0, "acc_m_s2": 3.0, "approach_m": 0.05})
        run = subprocess.Popen([sys.executable, "-m", "fluidsense", "task", "run", str(task_file),
                                "--order", "60,100,80,40", "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True, cwd=REPO)
        box.wait_for(lambda s: s["digital_outputs"] & 0b10, 120, "the first grip")
        box.command({"cmd": "inject", "fault": "sensor_stuck", "after_s": 0.0})
        out, err = run.communicate(timeout=600)
    assert run.returncode == 4, err[-3000:]
    partial = json.loads(out)
    assert partial["completed"] is False and partial["fault"]["kind"] == "sensor_stuck"
    assert "task sorting stopped by fault sensor_stuck" in err and "Traceback" not in err


def test_calibrating_a_real_cell_without_a_terminal_is_refused_before_anything_starts(tmp_path):
    cell = cell_config(tmp_path, "cell-modbus-sim", driver={
        "sim_control_port": DELETE,  # a real cell: nobody but the operator places targets
        "host": "127.0.0.254"})  # nothing there: the refusal must come first
    out = subprocess.run([sys.executable, "-m", "fluidsense", "calibrate", "--config", str(cell),
                          "--out", str(tmp_path / "cal.json")], stdin=subprocess.DEVNULL, capture_output=True,
                         text=True, timeout=60, cwd=REPO)
    assert out.returncode == 2
    assert "stdin is not a terminal" in out.stderr and "--targets-from" in out.stderr and "--yes" in out.stderr
    assert not journal_path(tmp_path / "cal.json").exists()


def test_calibrate_cli_keeps_its_journal_and_resumes(tmp_path):
    """The CLI end to end on the simulated cell: a finished run leaves its journal; a
    second run refuses to overwrite it; --resume with nothing left to run fits at once."""
    out = tmp_path / "cal.json"
    base = [sys.executable, "-m", "fluidsense", "calibrate", "--profile", "sorting-gripper-quick",
            "--scene", "cylinder", "--set", "diameter_mm=40", "--target", "diameter_mm", "--values", "40,60,80", "--cycles", "2",
            "--drop-first", "1", "--out", str(out), "--json"]
    first = subprocess.run(base, capture_output=True, text=True, timeout=300, cwd=REPO)
    assert first.returncode == 0, first.stderr
    again = subprocess.run(base, capture_output=True, text=True, timeout=300, cwd=REPO)
    assert again.returncode == 2 and "--resume" in again.stderr
    resumed = subprocess.run([*base, "--resume"], capture_output=True, text=True, timeout=300, cwd=REPO)
    assert resumed.returncode == 0, resumed.stderr
    assert json.loads(resumed.stdout)["coeffs"] == pytest.approx(json.loads(first.stdout)["coeffs"])
