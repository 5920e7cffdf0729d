"""The gripper's requests in-process: the real handler (controller/requests/grip.py) on a
fake cell (support/requests.py), the cycle moved along by the test, samples fed block by
block in the fake's sample time. No controller, no sockets: what test_gripper.py checks
through a daemon, here at the handler's own boundary, with every event checked against
docs/zmq-schema.md."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
from fluidsense.common.errors import SafetyError, SequenceError
from fluidsense.controller.config.gripper import GripperConfig
from fluidsense.controller.cycles.analysis import Reference
from support.events import check
from support.requests import CALIBRATION, FakeCell, settle

CALIBRATED = GripperConfig(calibrations=[str(CALIBRATION)])  # p_eq = 0.0416 kPa/mm x D + 33.80 kPa
P0 = 63e3  # the profile's charge pressure
FREE_KPA = 33.0  # the free-air reference's level


def free_air(t_rel):
    """The free-air reference's actuator pressure, Pa, against time since opening."""
    return np.where(t_rel >= 0, FREE_KPA * 1e3 * (1 - np.exp(-np.maximum(t_rel, 0) / 0.3)), 0.0)


def with_reference() -> FakeCell:
    cell = FakeCell()
    t = np.arange(0.0, 20.0, 0.001)
    cell.references[P0] = Reference(t, free_air(t), cycle_id=1)
    return cell


def run(body):
    return asyncio.run(body())


def topics(cell):
    for topic, payload in cell.events:
        check(topic, {"schema": 2, "instance": "0123456789abcdef", "topic": topic, "seq": 1, "topic_seq": 1, "t_s": 0.0, "utc_s": 0.0, **payload})
    return [topic for topic, _ in cell.events]


async def grasp_a_60_mm_cylinder(cell, requests):
    """Grip: charge, open, an object touches at 0.4 s (dP 3.3 kPa), the windows close at
    36.3 kPa (60 mm on the calibration), the grip holds. Returns the grip's reply."""
    reply = await requests.answer({"cmd": "grip"})
    cell.feed(requests.grip, 1.5, 0.0)  # charging: the offset's samples
    cell.open()
    cell.feed(requests.grip, 5.0, lambda t: free_air(t) + 3.3e3 * (t >= 0.4))
    cell.measured(cell.result(36.3, has_reference=True, t_c_s=0.4))
    cell.hold()
    await settle()
    return reply


def test_grip_touch_hold_slip_and_release():
    cell = with_reference()

    async def body():
        requests = cell.requests(CALIBRATED, tasks=lambda file, order: None)
        reply = await grasp_a_60_mm_cylinder(cell, requests)
        holding = await requests.answer({"cmd": "status"})
        refused = []
        for request in ({"cmd": "grip"}, {"cmd": "measure"}, {"cmd": "task", "file": "sorting.yaml"},
                        {"cmd": "cycle"}):
            with pytest.raises(SequenceError) as exc:
                await requests.answer(request)
            refused.append(str(exc.value))
        cell.feed(requests.grip, 1.0, 36.3e3)  # held: steady
        cell.feed(requests.grip, 2.0, 35.47e3)  # the object slips to 40 mm and the pressure settles there
        released = await requests.answer({"cmd": "release"})
        cell.end()
        await settle()
        open_ = await requests.answer({"cmd": "status"})
        with pytest.raises(SequenceError, match="nothing to release: the gripper is open"):
            await requests.answer({"cmd": "release"})
        return reply, holding, refused, released, open_

    reply, holding, refused, released, open_ = run(body)
    assert reply == {"cycle_id": 1, "p0_kpa": 63.0, "reference": True}
    assert topics(cell) == ["contact", "grasp", "slip", "released"]
    (_, contact), (_, grasp), (_, slip), (_, end) = cell.events
    assert contact["t_c_s"] == pytest.approx(0.4, abs=0.011) and contact["at_s"] == pytest.approx(1.5 + 0.4, abs=0.011)
    assert grasp["object"] is True and grasp["contact"] is True and grasp["in_range"] is True
    (size,) = grasp["estimates"]
    assert size["quantity"] == "diameter" and size["status"] == "ok" and size["value_mm"] == pytest.approx(60, abs=0.5)
    assert size["lo_mm"] < 60 < size["hi_mm"] and grasp["features"]["p_eq_kpa"] == pytest.approx(36.3)
    assert holding["holding"] is True and holding["object"] is True and holding["gripper_op"] == "grip"
    assert holding["last_grasp"]["cycle_id"] == 1
    assert refused == ["holding (cycle 1): send release before grip", "holding (cycle 1): send release before measure",
                       "holding (cycle 1): send release before a task", "busy: cycle 1 is in hold"]
    assert slip["drop_kpa"] == pytest.approx(0.83, abs=0.03) and slip["p_kpa"] == pytest.approx(35.47)
    assert slip["object"] is True
    assert slip["estimates"][0]["value_mm"] == pytest.approx(40, abs=0.5)
    assert released == {"cycle_id": 1, "releasing": True, "state": "vent"} and ("let_go",) in cell.asked
    assert end["reason"] == "release" and end["ok"] is True and end["held_s"] >= 0
    assert open_["holding"] is False and open_["gripper_op"] is None


def test_a_grip_on_nothing_says_no_object_and_no_size():
    cell = with_reference()

    async def body():
        requests = cell.requests(CALIBRATED)
        await requests.answer({"cmd": "grip"})
        cell.feed(requests.grip, 1.5, 0.0)
        cell.open()
        cell.feed(requests.grip, 5.0, free_air)  # the free-air curve: nothing touched
        cell.measured(cell.result(FREE_KPA, has_reference=True, t_c_s=None))
        cell.hold()
        await settle()

    run(body)
    assert topics(cell) == ["grasp"]
    grasp = cell.events[0][1]
    assert grasp["object"] is False and grasp["contact"] is False and grasp["in_range"] is None
    assert grasp["estimates"][0]["status"] == "no_object" and grasp["estimates"][0]["value_mm"] is None


def test_a_measure_uncalibrated_without_reference_says_what_it_cannot_tell():
    cell = FakeCell()

    async def body():
        requests = cell.requests()
        reply = await requests.answer({"cmd": "measure"})
        cell.open()
        cell.measured(cell.result(34.0))
        await settle()
        with pytest.raises(SequenceError, match="cycle 1 is a measure: it vents by itself"):
            await requests.answer({"cmd": "release"})
        cell.end()
        await settle()
        return reply

    assert run(body) == {"cycle_id": 1, "p0_kpa": 63.0, "reference": False}
    assert topics(cell) == ["grasp", "released"]
    grasp, end = cell.events[0][1], cell.events[1][1]
    assert grasp["estimates"] == [] and grasp["object"] is None and grasp["contact"] is None
    assert "no free-air reference" in grasp["note"] and "no calibration" in grasp["note"]
    assert grasp["features"]["p_eq_kpa"] == pytest.approx(34.0) and grasp["features"]["dp_eq_kpa"] is None
    assert end["reason"] == "done" and end["command"] == "measure" and end["held_s"] is None


def test_release_is_refused_as_documented_and_a_grip_on_nothing_is_released():
    """docs/zmq-schema.md: release is refused with no grip running (open gripper), for a
    plain cycle and for a measure; a grip that closed on nothing still holds the actuator
    inflated: it is released like any other."""
    cell = with_reference()

    async def body():
        requests = cell.requests(CALIBRATED)
        refused = []
        with pytest.raises(SequenceError) as exc:
            await requests.answer({"cmd": "release"})
        refused.append(str(exc.value))
        await requests.answer({"cmd": "grip"})
        cell.feed(requests.grip, 1.5, 0.0)
        cell.open()
        cell.feed(requests.grip, 5.0, free_air)  # nothing touched
        cell.measured(cell.result(FREE_KPA, has_reference=True, t_c_s=None))
        cell.hold()
        await settle()
        released = await requests.answer({"cmd": "release"})
        again = await requests.answer({"cmd": "release"})  # while it vents
        cell.end()
        await settle()
        with pytest.raises(SequenceError) as exc:
            await requests.answer({"cmd": "release"})
        refused.append(str(exc.value))
        return refused, released, again

    refused, released, again = run(body)
    assert refused == ["nothing to release: the gripper is open"] * 2
    assert cell.events[0][1]["object"] is False
    assert released["releasing"] is True and again == {"cycle_id": 1, "releasing": True, "state": "vent"}
    assert ("let_go",) in cell.asked and cell.events[-1][0] == "released"


def test_the_reference_measure_says_no_object_not_a_size():
    """`measure` with store_reference, nothing in the gripper, on the shipped calibration
    (20-100 mm): the empty gripper's P_eq reads 34.63 kPa, about a 19.9 mm object. It is
    the free-air reference the operator asked for: no object, no size."""
    cell = FakeCell()

    async def body():
        requests = cell.requests(CALIBRATED)
        reply = await requests.answer({"cmd": "measure", "store_reference": True})
        cell.feed(requests.grip, 1.5, 0.0)
        cell.open()
        cell.feed(requests.grip, 5.0, free_air)
        cell.measured(cell.result(34.63))
        await settle()
        return reply

    assert run(body)["reference"] is False  # nothing to compare with: it is the reference
    assert ("start_cycle", None, True, False) in cell.asked
    grasp = cell.events[0][1]
    assert topics(cell)[0] == "grasp"
    assert grasp["object"] is False and grasp["contact"] is False and grasp["in_range"] is None
    (size,) = grasp["estimates"]
    assert size["status"] == "no_object" and size["value_mm"] is None and size["lo_mm"] is None
    assert "free-air reference stored" in grasp["note"]


def test_a_reading_at_the_range_s_edge_without_reference_is_out_of_range():
    """The same reading without any reference: the point estimate (19.9 mm) lies below the
    calibrated 20 mm, where an empty gripper reads too: the bound, not a size."""
    cell = FakeCell()

    async def body():
        requests = cell.requests(CALIBRATED)
        await requests.answer({"cmd": "measure"})
        cell.open()
        cell.measured(cell.result(34.63))
        await settle()

    run(body)
    grasp = cell.events[0][1]
    (size,) = grasp["estimates"]
    assert size["status"] == "out_of_range" and size["value_mm"] is None
    assert size["hi_mm"] == pytest.approx(20.0) and size["lo_mm"] is None  # "at most 20 mm"
    assert grasp["in_range"] is False


def test_wrong_requests_are_refused_and_nothing_starts():
    cell = FakeCell(refuse=SafetyError("p0 95 kPa outside the profile's limits [-5.0, 90.0] kPa"))

    async def body():
        requests = cell.requests()
        with pytest.raises(SafetyError, match=r"timeout_s 5 is shorter than this profile's grip: 25 s"):
            await requests.answer({"cmd": "grip", "timeout_s": 5})
        with pytest.raises(SafetyError, match="outside the profile's limits"):
            await requests.answer({"cmd": "grip", "p0_kpa": 95})
        with pytest.raises(SequenceError, match="nothing to release"):
            await requests.answer({"cmd": "release"})
        return (await requests.answer({"cmd": "status"}))["gripper_op"]

    assert run(body) is None and cell.events == []
    assert cell.asked == [("start_cycle", 95, False, True)]  # the limit is the cell's to check


def test_a_grip_is_released_while_charging_by_aborting_and_a_plain_cycle_is_not_the_gripper_s():
    cell = FakeCell()

    async def body():
        requests = cell.requests()
        await requests.answer({"cmd": "grip"})
        released = await requests.answer({"cmd": "release"})  # still charging: nothing has closed
        cell.end(aborted="released before actuation")
        await settle()
        await requests.answer({"cmd": "cycle"})
        with pytest.raises(SequenceError, match="cycle 2 is not a grip: send abort to stop it"):
            await requests.answer({"cmd": "release"})
        return released

    assert run(body)["releasing"] is True
    assert ("abort", "released before actuation") in cell.asked and ("let_go",) not in cell.asked
    assert cell.events[-1][1]["reason"] == "release" and cell.events[-1][1]["ok"] is False


def test_an_aborted_grip_ends_with_the_abort_s_reason():
    cell = with_reference()

    async def body():
        requests = cell.requests()
        cycle = (await requests.answer({"cmd": "grip"}))["cycle_id"]
        cell.feed(requests.grip, 1.5, 0.0)
        aborted = await requests.answer({"cmd": "abort", "reason": "client"})
        cell.end(aborted="client")
        await settle()
        return cycle, aborted, await requests.answer({"cmd": "status"})

    cycle, aborted, status = run(body)
    assert aborted == {"aborted": True} and topics(cell) == ["released"]
    end = cell.events[0][1]
    assert end["cycle_id"] == cycle and end["reason"] == "client" and end["ok"] is False
    assert status["holding"] is False and status["gripper_op"] is None


def test_a_grip_not_grasped_within_its_timeout_is_given_up():
    """timeout_s 25.5: just longer than the profile's plan (10 + 10 + 5 s); the valve never
    opens (an actuator that would not vent), so the grasp cannot come in time."""
    cell = FakeCell()

    async def body():
        requests = cell.requests()
        await requests.answer({"cmd": "grip", "timeout_s": 25.5})
        cell.feed(requests.grip, 25.0, 8e3)
        before = list(cell.asked)
        cell.feed(requests.grip, 1.0, 8e3)
        await settle()
        after = list(cell.asked)
        cell.end(aborted="grip timeout")
        await settle()
        return before, after

    before, after = run(body)
    assert ("abort", "grip timeout") not in before and after[-1] == ("abort", "grip timeout")
    assert after.count(("abort", "grip timeout")) == 1  # once, however many blocks come after
    assert topics(cell) == ["released"] and cell.events[0][1]["reason"] == "timeout"


def test_a_grip_held_past_max_hold_s_is_released():
    cell = with_reference()

    async def body():
        requests = cell.requests(GripperConfig(max_hold_s=1.0))
        await grasp_a_60_mm_cylinder(cell, requests)
        cell.feed(requests.grip, 0.9, 36.3e3)
        await settle()
        early = ("let_go",) in cell.asked
        cell.feed(requests.grip, 0.2, 36.3e3)
        await settle()
        late = ("let_go",) in cell.asked
        cell.end()
        await settle()
        return early, late

    assert run(body) == (False, True)
    assert cell.events[-1][0] == "released" and cell.events[-1][1]["reason"] == "max_hold_s"


def test_a_scene_changed_under_a_held_grip_runs_sample_time_in_virtual_time_only():
    asked = {}
    for virtual in (True, False):
        cell = with_reference()
        cell.virtual = virtual

        async def body():
            requests = cell.requests(CALIBRATED)
            await grasp_a_60_mm_cylinder(cell, requests)
            await requests.answer({"cmd": "scene", "scene": {"kind": "cylinder", "diameter_mm": 40}})

        run(body)
        asked[virtual] = [a for a in cell.asked if a[0] == "wait"]
    assert asked == {True: [("wait", 2.0)], False: []}  # gripper.settle_s


def test_a_bug_while_following_a_grip_vents_and_opens_the_gripper():
    cell = FakeCell()

    async def body():
        requests = cell.requests()
        await requests.answer({"cmd": "grip"})
        cell._measured.set_exception(RuntimeError("injected"))
        await settle()
        return (await requests.answer({"cmd": "status"}))["gripper_op"]

    assert run(body) is None
    assert cell.asked[-1] == ("fail", "gripper: RuntimeError: injected")
