"""The examples under examples/ against ``fluidsense simcell`` (the emulated UR control
box) and a daemon subprocess on config/cell-gripper-modbus-sim.yaml: they run, exit 0 and
do what they say. pick_and_place.py is the integrator's motion stack: it moves the box's
arm with the real ur_rtde while the daemon holds the grip, which makes it the test of
holding while the arm moves. ros2_gripper_node.py needs ROS 2: not run."""

from __future__ import annotations

import csv
import subprocess
import sys

import pytest
import yaml
from fluidsense.client import Gripper
from support.gripper import drain
from support.harness import REPO, Daemon, free_simcell

EXAMPLES = REPO / "examples"
sys.path.insert(0, str(EXAMPLES))
import pick_and_place  # noqa: E402 - the example's own poses, so that the world matches them

CYLINDER = {"name": "cyl60", "diameter_mm": 60, "min_grip_kpa": 0.5}
WORLD = {"slots": [{"name": "pick", "pose": pick_and_place.PICK, "object": "cyl60"},
                   {"name": "place", "pose": pick_and_place.PLACE}],
         "objects": [CYLINDER]}


def test_pick_and_place_holds_the_cylinder_while_ur_rtde_moves_the_arm(tmp_path):
    with free_simcell(tmp_path, "gripper-modbus") as (box, cell):
        box.command({"cmd": "world", "world": WORLD})
        data = yaml.safe_load(cell.read_text())
        host = data["driver"]["host"]  # the box's address (ur_rtde's too)
        # The emulated box, a Python process, stops answering for a moment while it loads
        # ur_rtde's control script (the example's connection): the daemon's samples pause
        # for longer than the default 0.5 s (a no_data fault, none missed). A real box does
        # not: here the pause is let pass (a fault afterwards still fails the test).
        data["supervision"] = {"no_data_s": 5.0}
        cell.write_text(yaml.safe_dump(data))
        d = Daemon(cell)
        try:
            d.wait_welcome()
            with Gripper(d.cmd, d.pub, topics=("contact", "grasp", "slip", "released", "fault")) as g:
                drain(g, "released", g.measure(store_reference=True, wait=False))  # free air, away from the slots
                out = subprocess.run([sys.executable, str(EXAMPLES / "pick_and_place.py"), "--robot", host,
                                      "--cmd", d.cmd, "--pub", d.pub, "--speed", "0.5", "--acc", "1.0"],
                                     capture_output=True, text=True, timeout=300, cwd=REPO)
                assert out.returncode == 0, out.stdout + out.stderr
                assert "grasp: object True, diameter" in out.stdout and "arm: retract" in out.stdout
                first = g.next_event(60)  # the example's grip: its events wait in our subscription
                assert first is not None
                events = [first, *drain(g, "released", first.data["cycle_id"])]
                # held from the grasp to the release, through lift, carry and place: no slip, no fault
                assert [e.topic for e in events] == ["contact", "grasp", "released"], [e.data for e in events]
                grasp, released = events[1].data, events[2].data
                (est,) = grasp["estimates"]
                assert grasp["object"] is True and est["value_mm"] == pytest.approx(60, abs=2)
                assert released["reason"] == "release" and released["ok"] and released["held_s"] > 0
                status = g.status()
                assert status["holding"] is False and status["fault"] is None
            world = box.command({"cmd": "truth"})["truth"]["world"]
        finally:
            rc = d.close()
        assert rc == 0, d.stderr_now()
    # the box's world: closed at the pick slot, carried (held well enough to lift), opened at the place slot
    assert world["content"] == {"pick": None, "place": "cyl60"} and world["holding"] is None
    kinds = [(e["event"], e.get("slot"), e.get("object")) for e in world["events"]]
    assert ("close", "pick", "cyl60") in kinds and ("open", "place", "cyl60") in kinds
    assert [e["event"] for e in world["events"]].count("picked") == 1
    assert not any(e["event"] in ("not_held", "dropped", "slipped") for e in world["events"]), world["events"]


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
    rows = list(csv.DictReader(out.open()))
    assert [r["topic"] for r in rows] == ["grasp", "grasp"]
    assert rows[0]["object"] == "False" and rows[1]["object"] == "True"  # the reference: nothing there
    assert abs(float(rows[1]["value_mm"]) - 80) < 2 and float(rows[1]["lo_mm"]) < 80 < float(rows[1]["hi_mm"])
    assert rows[1]["status"] == "ok"
