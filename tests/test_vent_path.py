"""What vents the gripper when the link or the daemon dies, as ``status``, the heartbeat
and ``fluidsense check`` say it (docs/safety.md, "Vent without the PC"), and the sample
loop's real-time priority beside it."""

from __future__ import annotations

import subprocess
import sys

import pytest
from fluidsense.controller.config import load_cell_config
from fluidsense.controller.safety.ventpath import vent_path
from support.configs import cell_config
from support.events import check as check_schema
from support.harness import CONFIG, REPO, free_simcell, sim_config


@pytest.mark.parametrize("name, by, timeout_s", [
    ("cell-gripper-modbus-sim", "none", None),
    ("cell-modbus-sim", "box_watchdog", 0.5),
    ("cell-ur-sim", "box_watchdog", 0.5),
    ("cell-serial-sim", "device_watchdog", 0.5),
    ("cell-nidaqmx", "device_watchdog", 0.5),
    ("cell-sim", "no_link", None),
])
def test_each_shipped_config_says_what_vents_on_a_dead_link(name, by, timeout_s):
    cfg = load_cell_config(CONFIG / f"{name}.yaml")
    path = vent_path(cfg)
    assert path["by"] == by and path["timeout_s"] == timeout_s
    assert (path["fix"] is None) == (by != "none")


def test_without_a_vent_path_it_says_how_long_from_the_config_and_the_fix(tmp_path):
    cell = cell_config(tmp_path, "cell-gripper-modbus-sim", supervision={"no_data_s": 1.0},
                       driver={"reconnect": {"max_s": 4.0}})
    path = vent_path(load_cell_config(cell))
    assert path["by"] == "none" and path["fault_after_s"] == 1.0 and path["after_link_returns_s"] == 4.0
    assert path["pressurised"].startswith("until the link returns, plus up to 4 s (reconnect.max_s)")
    assert "within 1 s (supervision.no_data_s)" in path["pressurised"]
    assert "fluidsense watchdog --config" in path["fix"] and "program: integrator" in path["fix"]
    # the fix applied: the integrator's program carries the thread, the daemon beats it
    fixed = cell_config(tmp_path, "cell-gripper-modbus-sim", driver={"watchdog": {"program": "integrator"}})
    assert vent_path(load_cell_config(fixed))["by"] == "box_watchdog"
    # with an arm, the fix is ur_rtde's RTDE watchdog
    armed = cell_config(tmp_path, "cell-modbus-sim", driver={"watchdog": None})
    assert "RTDE watchdog" in vent_path(load_cell_config(armed))["fix"]


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
