"""The closed-loop tasks on the simulated cell, in virtual time, scored against the truth.

(Its in-process tests: tests/unit/test_tasks.py.)
"""

from __future__ import annotations

import json
import subprocess
import sys

import jsonschema
from support.events import SCHEMAS
from support.harness import CONFIG, REPO, sim_config
from unit import test_tasks as tasks_in_process

TASKS = CONFIG / "tasks"


def test_task_command_with_order_and_json():
    out = subprocess.run([sys.executable, "-m", "fluidsense", "task", "run", str(TASKS / "sorting.yaml"),
                          "--order", "100,40,60,80", "--json"], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    s = json.loads(out.stdout)
    assert s["success"] and s["input_order_mm"] == [100, 40, 60, 80]
    assert s["final_order_mm"] == [100, 80, 60, 40] and s["duration_s"] > 60


def test_task_started_through_the_command_socket(tmp_path, daemon_factory):
    path = sim_config(tmp_path, profile=str(CONFIG / "profiles" / "sorting-gripper-quick.yaml"))  # short cycles
    d = daemon_factory(path, "--tasks-dir", str(TASKS))
    d.wait_welcome()
    outside = d.request({"cmd": "task", "file": "../cell-sim.yaml"})
    assert outside["ok"] is False and "not a YAML file in" in outside["error"]
    missing = d.request({"cmd": "task", "file": "nope.yaml"})
    assert missing["ok"] is False
    reply = d.request({"cmd": "task", "file": "sorting.yaml", "order_mm": [80, 40, 100, 60]})
    assert reply == {"ok": True, "task": "sorting.yaml", "started": True}
    assert d.request({"cmd": "task", "file": "sorting.yaml"})["error"].startswith("busy")
    events = []
    while not events or events[-1]["event"] != "finished":
        _, m = d.next_message("task", timeout_s=120)
        jsonschema.validate(m, SCHEMAS["task"])  # as documented
        events.append(m)
    assert events[0]["event"] == "started"
    assert sum(e["event"] == "measured" for e in events) == 4
    summary = events[-1]["summary"]
    assert summary["success"] and summary["final_order_mm"] == [100, 80, 60, 40]
    assert d.request({"cmd": "status"})["task"] == {"file": "sorting.yaml", "running": False}


# in this process (tests/unit/test_tasks.py's run_file), but a study: the ripeness task's
# calibration and two rounds in virtual time, 28-38 s on the shared 2-core machine and past
# the unit tier's minute on a loaded one
def test_ripeness_picks_out_the_overripe_tomato_in_every_round():
    s = tasks_in_process.run_file("ripeness.yaml", edit={"rounds": 2})  # the shipped file: 5 rounds
    assert s["success_rate"] == 1.0 and len(s["rounds"]) == 2
    for rnd in s["rounds"]:
        assert rnd["flagged"] == ["overripe"]
        dummy = next(o for o in rnd["objects"] if o["object"] == "dummy-50")
        assert abs(dummy["mean_mm"]) < 2.0  # a rigid object is not squeezed
    assert s["calibration"]["points"] == 15  # 5 dummies x 3 grips (the first only aligns)
