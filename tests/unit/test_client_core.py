"""The client library's one core (fluidsense/client/core.py) and its two faces.

The core's calls do no I/O: here they are driven step by step from a script (what the
daemon would send), then the blocking and the asyncio face, and the CLI's ``send_command``,
run against a real ZeroMQ ROUTER in this process that leaves the first request
unanswered: the request socket must be made again for the next one to get through.

(Its tests with real peers: tests/system/test_client_core.py.)
"""

from __future__ import annotations

import json
from fluidsense.client import DaemonRestarted, GripEnded, NoReply, Refused
from fluidsense.client.core import Exchange, Listen, Session
from fluidsense.common.errors import FluidsenseError
from fluidsense.common.names import WELCOME, welcome_frame


def event(topic: str, seq: int, **data) -> list[bytes]:
    msg = {"schema": 1, "topic": topic, "seq": seq, "topic_seq": seq, "t_s": float(seq), "utc_s": 0.0, **data}
    return [topic.encode(), json.dumps(msg).encode()]


def drive(call, answers: list):
    """Run a core call on scripted I/O: each step gets the next answer. Returns (the
    call's result or the exception it raised, the steps it took)."""
    steps = []
    try:
        step = next(call)
        while True:
            steps.append(step)
            step = call.send(answers.pop(0))
    except StopIteration as end:
        return end.value, steps
    except Exception as exc:  # noqa: BLE001 - what the call raised is the result here
        return exc, steps


def ok(**fields) -> bytes:
    return json.dumps({"ok": True, **fields}).encode()


# ------------------------------------------------------------------ the core, step by step
def test_a_request_waits_for_the_welcome_and_an_error_reply_is_refused():
    session = Session("cmd", "pub", timeout_s=2.0, event_timeout_s=60.0)
    before = event("state", 1, cycle_id=0)
    reply, steps = drive(session.request({"cmd": "status"}), [before, [WELCOME], ok(state="idle")])
    assert reply == {"ok": True, "state": "idle"} and session.attached
    assert [type(s) for s in steps] == [Listen, Listen, Exchange] and steps[2].timeout_s == 2.0
    assert json.loads(steps[2].body) == {"cmd": "status"}
    refused, steps = drive(session.request({"cmd": "grip"}), [json.dumps({"ok": False, "error": "busy"}).encode()])
    assert isinstance(refused, Refused) and refused.reply["error"] == "busy" and len(steps) == 1
    late, _ = drive(session.request({"cmd": "status"}, timeout_s=0.5), [None])
    assert isinstance(late, NoReply) and "no reply to 'status' from cmd" in str(late)


def test_a_request_only_client_never_listens():
    session = Session("cmd", None, timeout_s=2.0, event_timeout_s=60.0)
    reply, steps = drive(session.status(), [ok(state="idle")])
    assert reply["state"] == "idle" and [type(s) for s in steps] == [Exchange]
    failed, steps = drive(session.next_event(1.0), [])
    assert isinstance(failed, ValueError) and "subscribes to nothing" in str(failed) and steps == []


def test_a_wait_keeps_the_other_events_in_order_for_later():
    session = Session("cmd", "pub", timeout_s=2.0, event_timeout_s=60.0)
    session.attached = True
    script = [event("contact", 1, cycle_id=3), event("state", 2, cycle_id=3), [b"garbage"],
              event("grasp", 3, cycle_id=3)]
    grasp, steps = drive(session.wait_for("grasp", 3, 10.0), script)
    assert grasp.topic == "grasp" and grasp.seq == 3 and len(steps) == 4
    assert all(isinstance(s, Listen) and 0 < s.timeout_s <= 10.0 for s in steps)
    assert [drive(session.next_event(0), [])[0].topic for _ in range(2)] == ["contact", "state"]
    nothing, steps = drive(session.next_event(0), [None])
    assert nothing is None and steps == [Listen(0.0)]


def test_a_grip_whose_cycle_ends_first_says_how_it_ended():
    session = Session("cmd", "pub", timeout_s=2.0, event_timeout_s=60.0)
    session.attached = True
    released = event("released", 1, cycle_id=4, command="grip", at_s=1.0, reason="fault: leak", held_s=None, ok=False)
    ended, steps = drive(session.grip(timeout_s=30.0), [ok(cycle_id=4, p0_kpa=63.0, reference=True), released])
    assert isinstance(ended, GripEnded) and ended.released.reason == "fault: leak" and not ended.released.ok
    assert steps[1].timeout_s <= 30.0 + 2.0  # the grip's own timeout plus a reply's
    assert drive(session.next_event(0), [])[0].topic == "released"  # kept for whoever reads the events


def test_a_release_of_a_grip_that_opened_by_itself_says_why_it_opened():
    """The daemon refuses a release once the grip is open (a fault vented it during the
    carry); the client that held it says the grip's own end, not only the refusal."""
    session = Session("cmd", "pub", timeout_s=2.0, event_timeout_s=60.0)
    session.attached = True
    grasp = event("grasp", 1, cycle_id=5, command="grip", object=True, contact=True, t_c_s=0.1, estimates=[],
                  in_range=None, features={}, note=None)
    got, _ = drive(session.grip(), [ok(cycle_id=5, p0_kpa=63.0, reference=True), grasp])
    assert got.cycle_id == 5 and session.held == (5, "")
    refusal = json.dumps({"ok": False, "error": "nothing to release: the gripper is open"}).encode()
    released = event("released", 2, cycle_id=5, command="grip", at_s=3.0, reason="fault: no_data", held_s=1.5,
                     ok=False)
    ended, steps = drive(session.release(), [refusal, event("state", 3, cycle_id=5), released])
    assert isinstance(ended, GripEnded) and ended.released.reason == "fault: no_data"
    assert "cycle 5 ended before its release: fault: no_data" in str(ended)
    assert isinstance(ended.__cause__, Refused) and session.held is None
    assert all(s.timeout_s <= 2.0 for s in steps[1:])  # a reply's wait, not an event's
    # a client that holds nothing is told the refusal as it came
    again, steps = drive(session.release(), [refusal])
    assert isinstance(again, Refused) and not isinstance(again, GripEnded) and len(steps) == 1
    # and if the event never comes (read by someone else), the refusal is not lost
    session.held = (6, "")
    silent, _ = drive(session.release(), [refusal, None])
    assert isinstance(silent, Refused) and "nothing to release" in str(silent)


def test_a_wait_ends_when_another_daemon_instance_welcomes_and_never_takes_its_cycle():
    """A grip on daemon X waits; X stops and Y starts on the same endpoints (its welcome);
    Y's cycle 1 is another client's. The wait ends at Y's welcome with DaemonRestarted,
    and Y's grasp of cycle 1 is never taken for X's."""
    x, y = "a" * 16, "b" * 16
    session = Session("cmd", "pub", timeout_s=2.0, event_timeout_s=60.0)
    grasp_y = event("grasp", 2, cycle_id=1, instance=y)
    ended, steps = drive(session.grip(), [[welcome_frame(x)], ok(cycle_id=1, p0_kpa=63.0, reference=True, instance=x),
                                          event("contact", 1, cycle_id=1, instance=x), [welcome_frame(y)], grasp_y])
    assert isinstance(ended, DaemonRestarted) and isinstance(ended, FluidsenseError) and isinstance(ended, ConnectionError)
    assert (ended.waited, ended.now) == (x, y) and "restarted" in str(ended)
    assert len(steps) == 4  # welcome, reply, contact, Y's welcome: ended there, Y's grasp not read
    # an event of another instance with the cycle id waited for is passed over, even without its welcome
    session = Session("cmd", "pub", timeout_s=2.0, event_timeout_s=60.0)
    late, _ = drive(session.grip(), [[welcome_frame(x)], ok(cycle_id=1, p0_kpa=63.0, reference=True, instance=x),
                                     grasp_y, None])
    assert isinstance(late, NoReply)
    assert drive(session.next_event(0), [])[0].instance == y  # kept for whoever reads the events
    # a welcome again from the same instance (a dropped connection) ends nothing
    session = Session("cmd", "pub", timeout_s=2.0, event_timeout_s=60.0)
    grasp, _ = drive(session.grip(), [[welcome_frame(x)], ok(cycle_id=1, p0_kpa=63.0, reference=True, instance=x),
                                      [welcome_frame(x)], event("grasp", 5, cycle_id=1, instance=x, object=True,
                                      contact=True, t_c_s=0.1, estimates=[], in_range=True, features={}, note=None)])
    assert grasp.cycle_id == 1 and grasp.event.instance == x
