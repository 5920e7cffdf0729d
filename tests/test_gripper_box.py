"""The daemon as a gripper against the emulated UR control box (``fluidsense simcell``):
the production drivers (Modbus, ur-rtde) in a daemon subprocess, driven through the client
library, every event checked against docs/zmq-schema.md.

The cell is config/cell-gripper-modbus-sim.yaml: the PneuNet gripper with its short
protocol (config/profiles/pneunet-gripper-quick.yaml) on a +-103.4 kPa sensor (its grip
reads 34-38 kPa), calibrated by config/calibrations/pneunet-gripper-quick-p_eq.json, which
``fluidsense calibrate`` made against this same emulated box through the Modbus driver.
The box runs in real time: the waits below are bounded by the daemon's events, nothing
asserts on wall-clock speed.
"""

from __future__ import annotations

import pytest
from fluidsense.client import Gripper
from support.configs import read, whole
from support.gripper import grip_a_60_mm_cylinder, slip_to_40_mm
from support.harness import CONFIG, Daemon, free_simcell

GRIPPER_CELL = read(CONFIG / "cell-gripper-modbus-sim.yaml")
# the ur-rtde driver on the same box wiring (arm and box watchdog through ur_rtde's script),
# with the gripper's calibrations
UR_GRIPPER = {"driver": {"wiring": whole(GRIPPER_CELL["driver"]["wiring"])},
              "gripper": {"calibrations": [str(CONFIG / c) for c in GRIPPER_CELL["gripper"]["calibrations"]]}}


@pytest.mark.parametrize("kind", ["gripper-modbus", "ur"])
def test_grip_a_60_mm_cylinder_let_it_slip_then_grip_nothing_through_the_box(kind, tmp_path):
    """Modbus: the gripper cell as shipped. ur: the same gripper and wiring through the
    ur-rtde driver (the box's program is then the daemon's control script); the
    calibration made through Modbus applies, as it calibrates the gripper, not the path."""
    profile = "pneunet-gripper-quick.yaml" if kind == "ur" else None
    with free_simcell(tmp_path, kind, profile=profile, **(UR_GRIPPER if kind == "ur" else {})) as (_, cell):
        d = Daemon(cell)
        try:
            d.wait_welcome()
            with Gripper(d.cmd, d.pub, topics=("contact", "grasp", "slip", "released", "fault")) as g:
                cycle = grip_a_60_mm_cylinder(g, t_c_max_s=2.0)
                # the scene changes in the box's plant, over its sim-control port
                slip_to_40_mm(g, cycle)

                released = g.release()
                assert released.cycle_id == cycle and released.reason == "release" and released.ok
                assert g.status()["holding"] is False

                g.scene({"kind": "none"})
                empty = g.grip()
                assert empty.object is False and empty.contact is False and empty.in_range is None
                assert empty.size.status == "no_object" and empty.size.value_mm is None
                assert g.release().reason == "release"
                # nothing went wrong on the way: no slip, no fault among the events left
                left = []
                while (ev := g.next_event(0.5)) is not None:
                    left.append(ev.topic)
                assert "slip" not in left and "fault" not in left, left
        finally:
            rc = d.close()
        assert rc == 0, d.stderr_now()
