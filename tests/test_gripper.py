"""The daemon as a gripper: grip, hold, slip, release and measure over real sockets, driven
through the client library (fluidsense.client), every event checked against
docs/zmq-schema.md. Virtual time on the simulated cell with the pneunet gripper and the
shipped calibration (config/calibrations/pneunet-gripper-p_eq.json)."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest
import yaml

from fluidsense.client import AsyncGripper, GripEnded, Gripper, Refused

from .conftest import REPO, sim_config
from .test_zmq import check

CALIBRATION = REPO / "config" / "calibrations" / "pneunet-gripper-p_eq.json"


def gripper_config(tmp_path, calibrated: bool = True, **gripper):
    path = sim_config(tmp_path, clock="virtual")
    data = yaml.safe_load(path.read_text())
    data["gripper"] = {"calibrations": [str(CALIBRATION)] if calibrated else [], **gripper}
    path.write_text(yaml.safe_dump(data))
    return path


def drain(g: Gripper, until: str, cycle_id: int) -> list:
    """Events up to and including ``until`` of the cycle, each checked against the document;
    when ``until`` does not come, the failure says the daemon's last grasp and fault."""
    seen = []
    while True:
        ev = g.next_event(60)
        if ev is None:
            status = g.status()
            raise AssertionError(f"no {until} of cycle {cycle_id}; got {[e.topic for e in seen]}; last grasp: "
                                 f"{status.get('last_grasp')}; fault: {status.get('fault')}")
        check(ev.topic, ev.data)
        seen.append(ev)
        if ev.topic == until and ev.data["cycle_id"] == cycle_id:
            return seen


def grip_a_60_mm_cylinder(g: Gripper, t_c_max_s: float) -> int:
    """A free-air reference, then a grip on a 60 mm cylinder: contact within ``t_c_max_s``,
    then the grasp, sized within 2 mm, and the gripper holding. Returns the grip's cycle."""
    drain(g, "released", g.measure(store_reference=True, wait=False))
    g.scene({"kind": "cylinder", "diameter_mm": 60})
    cycle = g.grip(wait=False)
    events = drain(g, "grasp", cycle)
    assert [e.topic for e in events] == ["contact", "grasp"]
    contact, grasp = events
    assert 0 < contact.data["t_c_s"] < t_c_max_s and contact.data["at_s"] < grasp.data["at_s"]
    assert grasp.data["object"] is True and grasp.data["in_range"] is True
    (est,) = grasp.data["estimates"]
    assert est["quantity"] == "diameter" and est["status"] == "ok"
    assert est["value_mm"] == pytest.approx(60, abs=2) and est["lo_mm"] < 60 < est["hi_mm"]
    status = g.status()
    assert status["holding"] is True and status["object"] is True and status["state"] == "hold"
    return cycle


def slip_to_40_mm(g: Gripper, cycle: int) -> None:
    """The held object slips to a thinner part between the fingers: one slip, still an
    object, the new size."""
    g.scene({"kind": "cylinder", "diameter_mm": 40})
    (slip,) = [e for e in drain(g, "slip", cycle) if e.topic == "slip"]
    assert slip.data["drop_kpa"] > 0.5 and slip.data["object"] is True
    assert slip.data["estimates"][0]["value_mm"] == pytest.approx(40, abs=3)


def test_grip_a_cylinder_hold_it_slip_release_and_grip_nothing(tmp_path, daemon_factory):
    d = daemon_factory(gripper_config(tmp_path))
    d.wait_welcome()
    with Gripper(d.cmd, d.pub, topics=("contact", "grasp", "slip", "released", "fault")) as g:
        cycle = grip_a_60_mm_cylinder(g, t_c_max_s=1.0)
        assert g.status()["last_grasp"]["cycle_id"] == cycle

        # wrong state: refused with a reason, nothing changes
        with pytest.raises(Refused, match="send release before grip"):
            g.grip()
        with pytest.raises(Refused, match="send release before measure"):
            g.measure()
        with pytest.raises(Refused, match="busy"):
            g.request({"cmd": "cycle"})
        assert g.status()["holding"] is True

        # the object slips to a thinner part between the fingers: one slip, still an object
        slip_to_40_mm(g, cycle)
        released = g.release()
        assert released.cycle_id == cycle and released.reason == "release" and released.ok
        assert released.held_s is not None and released.held_s >= 0
        assert g.status()["holding"] is False
        with pytest.raises(Refused, match="nothing to release"):
            g.release()

        # nothing there: the grasp says so, with no size
        g.scene({"kind": "none"})
        empty = g.grip()
        assert empty.object is False and empty.contact is False and empty.in_range is None
        assert empty.size.status == "no_object" and empty.size.value_mm is None
        assert g.release().reason == "release"


def test_wrong_requests_are_refused_and_a_grip_can_be_aborted(tmp_path, daemon_factory):
    d = daemon_factory(gripper_config(tmp_path, calibrated=False))
    d.wait_welcome()

    async def go():
        async with AsyncGripper(d.cmd, d.pub) as g:
            with pytest.raises(Refused, match="shorter than this profile's grip"):
                await g.grip(timeout_s=5)
            with pytest.raises(Refused, match="outside the profile's limits"):
                await g.grip(p0_kpa=95)
            with pytest.raises(Refused, match="timeout_s"):
                await g.request({"cmd": "grip", "timeout_s": -1})
            # uncalibrated, no reference: the grasp says what it cannot tell
            grasp = await g.measure()
            assert grasp.estimates == () and grasp.object is None and "no calibration" in grasp.note
            assert grasp.features["p_eq_kpa"] > 30
            cycle = await g.grip(wait=False)
            assert await g.abort("client") is True
            with pytest.raises(GripEnded) as ended:
                await g.wait_for("grasp", cycle, 60, fail_on_end=True)
            assert ended.value.released.reason == "client" and not ended.value.released.ok
            status = await g.status()
            assert status["holding"] is False and status["state"] in ("vent", "idle")

    asyncio.run(go())


def test_a_grip_held_past_max_hold_s_is_released(tmp_path, daemon_factory):
    """A timeout_s just long enough for this profile's grasp (10 + 10 + 5 s of sample
    time) still grasps; a grip held beyond gripper.max_hold_s is released (vents)."""
    d = daemon_factory(gripper_config(tmp_path, calibrated=False, max_hold_s=1.0))
    d.wait_welcome()
    with Gripper(d.cmd, d.pub) as g:
        assert g.grip(timeout_s=25.5).object is None
        g.scene({"kind": "cylinder", "diameter_mm": 60})  # sample time runs on: the hold limit passes
        released = g.wait_for("released", None, 60)
        assert released.data["reason"] == "max_hold_s"


def test_a_grip_not_grasped_within_its_timeout_is_given_up_and_vented(tmp_path, daemon_factory):
    """The tube still holds 8 kPa when the daemon starts and the profile charges and
    isolates for only 0.5 s each: the first grip waits (about 2 s) for the actuator to
    vent before its valve opens, so its grasp cannot come within a timeout_s just long
    enough for the plan (0.5 + 0.5 + 5 s): the grip is given up and vented, and says so.
    The next grip, on the vented actuator, grasps within the same timeout."""
    path = gripper_config(tmp_path, calibrated=False)
    data = yaml.safe_load(path.read_text())
    profile = yaml.safe_load(Path(data["profile"]).read_text())
    profile["sequence"].update(charge_s=0.5, isolate_s=0.5)
    data["profile"] = profile
    data["driver"]["perturb"] = {"residual_kpa": 8.0}
    path.write_text(yaml.safe_dump(data))
    d = daemon_factory(path)
    d.wait_welcome()
    with Gripper(d.cmd, d.pub) as g:
        cycle = g.grip(timeout_s=6.5, wait=False)
        with pytest.raises(GripEnded) as ended:
            g.wait_for("grasp", cycle, 60, fail_on_end=True)
        assert ended.value.released.reason == "timeout" and not ended.value.released.ok
        status = g.status()
        assert status["holding"] is False and status["fault"] is None
        assert status["state"] in ("vent", "idle")
        for _ in range(100):  # the vent runs on in sample time (each status is a round trip)
            if g.status()["state"] == "idle":
                break
        assert g.grip(timeout_s=6.5).object is None  # uncalibrated: grasped, nothing to say about it
        assert g.release().reason == "release"


def test_a_calibration_of_another_profile_stops_the_daemon_before_it_starts(tmp_path):
    import json
    import subprocess
    import sys

    other = json.loads(CALIBRATION.read_text()) | {"profile": "sorting-gripper"}
    (tmp_path / "other.json").write_text(json.dumps(other))
    path = gripper_config(tmp_path)
    data = yaml.safe_load(path.read_text())
    data["gripper"]["calibrations"] = ["other.json"]  # relative to the cell config
    path.write_text(yaml.safe_dump(data))
    out = subprocess.run([sys.executable, "-m", "fluidsense.cli", "run", "--config", str(path)], cwd=REPO,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert f"{path}: gripper.calibrations.0: " in out.stderr and "calibrates profile 'sorting-gripper'" in out.stderr
