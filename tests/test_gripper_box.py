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
import yaml

from fluidsense.client import Gripper

from .conftest import CONFIG, Daemon, free_simcell
from .test_gripper import drain as _drain


def drain(g: Gripper, until: str, cycle_id: int) -> list:
    """The events up to ``until`` of the cycle (schema-checked); a fault among them fails
    the test with what it was."""
    try:
        return _drain(g, until, cycle_id)
    except AssertionError as exc:
        raise AssertionError(f"{exc}; last grasp: {g.status().get('last_grasp')}; fault: {g.status().get('fault')}") \
            from exc

GRIPPER_CELL = yaml.safe_load((CONFIG / "cell-gripper-modbus-sim.yaml").read_text())
# the ur-rtde driver on the same box wiring (arm and box watchdog through ur_rtde's script)
UR_DRIVER = {"wiring": GRIPPER_CELL["driver"]["wiring"]}


def _ur_gripper_cell(cell):
    data = yaml.safe_load(cell.read_text())
    data["gripper"] = {"calibrations": [str(CONFIG / c) for c in GRIPPER_CELL["gripper"]["calibrations"]]}
    cell.write_text(yaml.safe_dump(data))
    return cell


@pytest.mark.parametrize("kind", ["gripper-modbus", "ur"])
def test_grip_a_60_mm_cylinder_let_it_slip_then_grip_nothing_through_the_box(kind, tmp_path):
    """Modbus: the gripper cell as shipped. ur: the same gripper and wiring through the
    ur-rtde driver (the box's program is then the daemon's control script); the
    calibration made through Modbus applies, as it calibrates the gripper, not the path."""
    profile = "pneunet-gripper-quick.yaml" if kind == "ur" else None
    with free_simcell(tmp_path, kind, profile=profile, driver=UR_DRIVER if kind == "ur" else None) as (_, cell):
        if kind == "ur":
            cell = _ur_gripper_cell(cell)
        d = Daemon(cell)
        try:
            d.wait_welcome()
            with Gripper(d.cmd, d.pub, topics=("contact", "grasp", "slip", "released", "fault")) as g:
                drain(g, "released", g.measure(store_reference=True, wait=False))  # free air: the reference
                g.scene({"kind": "cylinder", "diameter_mm": 60})
                cycle = g.grip(wait=False)
                events = drain(g, "grasp", cycle)
                assert [e.topic for e in events] == ["contact", "grasp"]
                contact, grasp = events
                assert 0 < contact.data["t_c_s"] < 2.0 and contact.data["at_s"] < grasp.data["at_s"]
                assert grasp.data["object"] is True and grasp.data["in_range"] is True
                (est,) = grasp.data["estimates"]
                assert est["quantity"] == "diameter" and est["status"] == "ok"
                assert est["value_mm"] == pytest.approx(60, abs=2) and est["lo_mm"] < 60 < est["hi_mm"]
                status = g.status()
                assert status["holding"] is True and status["object"] is True and status["state"] == "hold"

                # the object slips to a thinner part between the fingers (the box's plant, over
                # its sim-control port): one slip, still an object, the new size
                g.scene({"kind": "cylinder", "diameter_mm": 40})
                (slip,) = [e for e in drain(g, "slip", cycle) if e.topic == "slip"]
                assert slip.data["drop_kpa"] > 0.5 and slip.data["object"] is True
                assert slip.data["estimates"][0]["value_mm"] == pytest.approx(40, abs=3)

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
