"""What vents the gripper when the link or the daemon dies, as ``status``, the heartbeat
and ``fluidsense check`` say it (docs/safety.md, "Vent without the PC"), and the sample
loop's real-time priority beside it.

(Its in-process tests: tests/unit/test_vent_path.py.)
"""

from __future__ import annotations

import subprocess
import sys
from support.events import check as check_schema
from support.harness import REPO, free_simcell, sim_config


def test_check_names_the_missing_vent_path_and_the_fix_without_failing_for_it(tmp_path):
    with free_simcell(tmp_path, "gripper-modbus") as (_, cell):
        r = subprocess.run([sys.executable, "-m", "fluidsense", "check", "--config", str(cell), "--seconds", "1"],
                           capture_output=True, text=True, timeout=120, cwd=REPO, stdin=subprocess.DEVNULL)
    out = r.stdout
    assert "vent path on a dead link" in out
    warning = "WARNING nothing vents the gripper when the link or the daemon dies: driver.watchdog is null"
    head, summary = out.split("\nresult\n", 1)
    assert warning in head and warning in summary, out
    assert "until the link returns, plus up to 10 s (reconnect.max_s)" in out
    assert "Fix: put the watchdog thread into the box's program (`fluidsense watchdog --config` prints it)" in out
    # a warning, not a problem: only the rate (a busy shared machine) may make it exit 4
    problems = [line.strip() for line in summary.splitlines()
                if line.strip() and not line.strip().startswith(("WARNING", "everything matches", "sampling:"))]
    assert problems == [] and r.returncode in (0, 4), out + r.stderr


def test_status_and_heartbeat_carry_the_vent_path_and_the_loops_scheduling(tmp_path, daemon_factory):
    d = daemon_factory(sim_config(tmp_path))  # virtual time: real-time priority is not needed
    d.wait_welcome()
    status = d.request({"cmd": "status"})
    assert status["vent_path"]["by"] == "no_link" and status["vent_path"]["fix"] is None
    assert status["realtime"] == {"sched_fifo": "not_needed", "priority": None, "detail": "virtual time"}
    assert d.request({"cmd": "cycle"})["ok"]  # sample time moves: a heartbeat comes
    _, beat = d.next_message("heartbeat", timeout_s=60)
    check_schema("heartbeat", beat)
    assert beat["realtime"] == "not_needed" and beat["vent_path"] == "no_link"
