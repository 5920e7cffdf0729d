"""What vents the gripper when the link or the daemon dies, as ``status``, the heartbeat
and ``fluidsense check`` say it (docs/safety.md, "Vent without the PC"), and the sample
loop's real-time priority beside it.

(Its tests with real peers: tests/system/test_vent_path.py.)
"""

from __future__ import annotations

import pytest
from fluidsense.controller.config import load_cell_config
from fluidsense.controller.safety.ventpath import vent_path
from support.configs import cell_config
from support.harness import CONFIG


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
