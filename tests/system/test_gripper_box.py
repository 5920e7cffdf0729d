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
                aligned = empty.features["rise_shift_s"] is not None  # see grip_a_60_mm_cylinder
                if empty.object is None:  # the alignment's residue on the rise: said, never an object
                    assert "the features disagree" in empty.note
                else:
                    assert empty.object is False and empty.contact is (False if aligned else None)
                    assert empty.size.status == "no_object" and empty.size.value_mm is None
                assert empty.in_range is None
                assert g.release().reason == "release"
                # nothing went wrong on the way: no slip, no fault among the events left
                left = []
                while (ev := g.next_event(0.5)) is not None:
                    left.append(ev.topic)
                assert "slip" not in left and "fault" not in left, left
        finally:
            rc = d.close()
        assert rc == 0, d.stderr_now()


def _opened(box):
    """When the actuation valve last really opened (box time, from the box's own log; read
    while the cycle holds, after its grasp). With when the daemon commanded it (sample time,
    from the cycle event after it ended, ``_commanded``), the difference between two cycles
    is the timing the alignment has to find: each clock's origin drops out, both run at the
    monotonic rate."""
    log = box.command({"cmd": "valve_log"})["valves"]
    return [v["effective_s"] for v in log if v["valve"] == "actuate" and v["open"]][-1]


def _commanded(g, cycle_id):
    return g.wait_for("cycle", cycle_id, 60.0).data["t_open_s"]


@pytest.mark.parametrize("kind", ["modbus", "ur"])
def test_the_sorting_gripper_reads_an_empty_grip_as_empty_whenever_its_valve_opens(kind, tmp_path):
    """The shipped sorting cells (config/cell-{modbus,ur}-sim.yaml, sorting-gripper, no
    per-profile alignment) through the emulated box. The free-air reference is taken while
    the valve commands reach the valve 6 ms late (a PC busy at that moment); the grips after
    it open 6 ms earlier than the reference did, give or take this PC's own latency, which
    the box's valve log measures. Against a fixed-timing reference that is 2-5 kPa of dP on
    the first rise (contact at about 9 ms, an object on free air: what the busy PC did to up
    to half of the empty grips). Lined up on the rise, an empty grip is empty, the shift found
    is the valve's true timing, and a 60 mm cylinder still an object. (Without the alignment
    and the judgement, on main a42adbc with only the box's command_lag added, every empty grip
    here read an object.)"""
    with free_simcell(tmp_path, kind, references={"keep": False}) as (box, cell):
        d = Daemon(cell)
        try:
            d.wait_welcome()
            with Gripper(d.cmd, d.pub, topics=("contact", "grasp", "released", "fault", "cycle")) as g:
                assert box.command({"cmd": "command_lag", "lag_s": 0.006})["ok"]
                g.scene({"kind": "none"})
                ref_id = g.measure(store_reference=True, wait=False)
                g.wait_for("grasp", ref_id, 60.0)
                ref_open = _opened(box)
                g.wait_for("released", ref_id, 60.0)
                ref_commanded = _commanded(g, ref_id)
                assert box.command({"cmd": "command_lag", "lag_s": 0.0})["ok"]
                for _ in range(3):
                    empty = g.grip()
                    grip_open = _opened(box)
                    g.release()
                    # how much earlier after its command this grip's valve opened than the
                    # reference's did: the 6 ms lag and whatever this PC added to either
                    true_shift = (grip_open - ref_open) - (_commanded(g, empty.cycle_id) - ref_commanded)
                    # a rise whose samples a busy PC missed is not aligned, and says so: contact
                    # then cannot be told, and the object is the equilibrium's
                    shift = empty.features["rise_shift_s"]
                    assert empty.object is not True, (empty.features, empty.note)
                    if shift is not None:
                        # within two sample periods of the truth (the samples are read, and
                        # so timed, on the PC's slots, not the box's)
                        period = 1.0 / read(cell)["driver"]["rate_hz"]
                        assert abs(shift - true_shift) < 2 * period, (shift, true_shift, empty.note)
                    if empty.object is None:
                        # a contact time left by the residue of the alignment on the steep
                        # rise, against a free-air equilibrium: said, never an object
                        assert "the features disagree" in empty.note
                        assert abs(empty.features["dp_eq_kpa"]) <= empty.features["object_bound_kpa"]
                    elif shift is not None:
                        assert empty.contact is False, (shift, empty.note)
                    else:
                        assert empty.contact is None and "could not be aligned" in empty.note
                g.scene({"kind": "cylinder", "diameter_mm": 60})
                held = g.grip()
                g.release()
                assert held.object is True, (held.features, held.note)
                if held.features["rise_shift_s"] is not None:
                    assert held.contact is True and 0.1 < held.t_c_s < 1.0, (held.features, held.note)
                else:  # the samples across the rise were missed: no contact time, and it says so
                    assert held.contact is None and "could not be aligned" in held.note
                left = []
                while (ev := g.next_event(0.5)) is not None:
                    left.append(ev.topic)
                assert "fault" not in left, left
        finally:
            rc = d.close()
        assert rc == 0, d.stderr_now()
