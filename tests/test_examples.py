"""The examples under examples/ against a daemon on the simulated cell (smoke level: they
run, exit 0 and produce what they say). ros2_gripper_node.py needs ROS 2: not run."""

from __future__ import annotations

import csv
import subprocess
import sys

from fluidsense.client import Gripper

from .conftest import REPO
from .test_gripper import gripper_config

EXAMPLES = REPO / "examples"


def test_pick_and_place_grips_carries_and_releases(tmp_path, daemon_factory):
    d = daemon_factory(gripper_config(tmp_path))
    d.wait_welcome()
    assert d.request({"cmd": "scene", "scene": {"kind": "cylinder", "diameter_mm": 60}})["ok"]
    out = subprocess.run([sys.executable, str(EXAMPLES / "pick_and_place.py"), "--cmd", d.cmd, "--pub", d.pub],
                         capture_output=True, text=True, timeout=120, cwd=REPO)
    assert out.returncode == 0, out.stderr
    assert "grasp: object None, diameter" in out.stdout  # no free-air reference was taken
    assert "released after" in out.stdout and "arm: retract" in out.stdout
    assert d.request({"cmd": "status"})["holding"] is False


def test_log_grasps_csv_writes_a_row_per_grasp(tmp_path, daemon_factory):
    d = daemon_factory(gripper_config(tmp_path))
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
    rows = list(csv.DictReader(out.open()))
    assert [r["topic"] for r in rows] == ["grasp", "grasp"]
    assert rows[0]["object"] == "" and rows[1]["object"] == "True"
    assert abs(float(rows[1]["value_mm"]) - 80) < 3 and rows[1]["status"] == "ok"
