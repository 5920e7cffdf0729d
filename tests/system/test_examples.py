"""The examples under examples/ against ``fluidsense simcell`` (the emulated UR control
box) and a daemon on config/cell-gripper-modbus-sim.yaml: they run, exit 0 and do what
they say. examples/README.md's shell block is run as written (its fenced ``sh`` lines, in
order). pick_and_place.py is the integrator's motion stack: it moves the box's arm with the
real ur_rtde while the daemon holds the grip, which makes it the test of holding while
the arm moves. ros2_gripper_node.py needs ROS 2: not run.

(Its acceptance runs: tests/accept/test_examples.py.)
"""

from __future__ import annotations

import csv
import subprocess
import sys
from fluidsense.client import Gripper
from support.harness import REPO, Daemon, free_simcell

EXAMPLES = REPO / "examples"


def test_log_grasps_csv_writes_a_row_per_grasp(tmp_path):
    with free_simcell(tmp_path, "gripper-modbus") as (_, cell):
        d = Daemon(cell)
        try:
            d.wait_welcome()
            out = tmp_path / "grasps.csv"
            logger = subprocess.Popen([sys.executable, str(EXAMPLES / "log_grasps_csv.py"), str(out), "--cmd", d.cmd,
                                       "--pub", d.pub, "--count", "2"], stderr=subprocess.PIPE, text=True, cwd=REPO)
            try:
                while not out.exists() or not out.read_text():  # the header is written once it is attached
                    assert logger.poll() is None, logger.stderr.read()
                    d.request({"cmd": "status"})  # paced by the daemon's replies, not by sleeping
                with Gripper(d.cmd, d.pub) as g:
                    g.measure(store_reference=True)
                    g.scene({"kind": "cylinder", "diameter_mm": 80})
                    g.measure()
                assert logger.wait(60) == 0
            finally:
                logger.kill()
        finally:
            rc = d.close()
        assert rc == 0, d.stderr_now()
    with out.open() as f:
        rows = list(csv.DictReader(f))
    assert [r["topic"] for r in rows] == ["grasp", "grasp"]
    assert rows[0]["object"] == "False" and rows[1]["object"] == "True"  # the reference: nothing there
    assert abs(float(rows[1]["value_mm"]) - 80) < 2 and float(rows[1]["lo_mm"]) < 80 < float(rows[1]["hi_mm"])
    assert rows[1]["status"] == "ok"
