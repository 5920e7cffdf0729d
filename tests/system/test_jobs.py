"""Jobs that a fault stops say so and keep what they did: tasks, calibration (with its
journal and --resume), sensing; and a real-cell calibration never reads a prompt that
nobody can answer.

(Its in-process tests: tests/unit/test_jobs.py.)
"""

from __future__ import annotations

import json
import subprocess
import sys
from support.configs import task_config
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
