"""The daemon as a gripper: grip, hold, slip, release and measure over real sockets, driven
through the client library (fluidsense.client), every event checked against
docs/zmq-schema.md. Virtual time on the simulated cell with the pneunet gripper and the
shipped calibration (config/calibrations/pneunet-gripper-p_eq.json).

(Its in-process tests: tests/unit/test_gripper.py.)
"""

from __future__ import annotations

import pytest
from fluidsense.client import Gripper, Refused
from support.gripper import grip_a_60_mm_cylinder, slip_to_40_mm
from support.harness import REPO, ipc_endpoints, sim_config

CALIBRATION = REPO / "config" / "calibrations" / "pneunet-gripper-p_eq.json"


def gripper_config(tmp_path, calibrated: bool = True, **gripper):
    return sim_config(tmp_path, clock="virtual",
                      gripper={"calibrations": [str(CALIBRATION)] if calibrated else [], **gripper})


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


def test_a_grip_waiting_across_a_daemon_restart_ends_and_never_takes_the_new_daemons_cycle(tmp_path, daemon_factory):
    """Client A waits in grip() on daemon X (real time: it is charging); X dies without a
    word (killed: no ``released`` for A's cycle, as after a crash or when that message is
    lost) and Y starts on the same endpoints, as systemd restarts it; client B grips on Y,
    whose cycle ids start at 1 again. A's grip ends with DaemonRestarted at Y's welcome;
    it used to return B's grasp (cycle 1). (A stopped X says ``released``: GripEnded.)"""
    import threading

    from fluidsense.client import DaemonRestarted

    endpoints = ipc_endpoints(tmp_path)

    def config(clock):
        return sim_config(tmp_path, clock=clock, endpoints=endpoints, scene={"kind": "cylinder", "diameter_mm": 60},
                          gripper={"calibrations": [str(CALIBRATION)]})

    x = daemon_factory(config("realtime"))  # a grip charges for seconds: A is waiting when X stops
    x.wait_welcome()
    outcome: list = []
    # event_timeout_s: a wait that is never ended (the old client) gives up within the test
    a = Gripper(x.cmd, x.pub, topics=("contact", "grasp", "slip", "released", "fault"), event_timeout_s=60.0)

    def grip_a():
        try:
            outcome.append(a.grip())
        except Exception as exc:  # noqa: BLE001 - what it raised is the result here
            outcome.append(exc)

    waiter = threading.Thread(target=grip_a, daemon=True)
    waiter.start()
    while x.request({"cmd": "status"})["gripper_op"] != "grip":  # paced by X's replies
        assert waiter.is_alive(), outcome  # A's grip ended before X took it
    first = x.instance
    x.proc.kill()  # its helper processes end with it (PR_SET_PDEATHSIG)
    assert x.proc.wait(30) == -9
    y = daemon_factory(config("virtual"))
    y.wait_welcome()
    assert y.instance != first
    try:
        with Gripper(y.cmd, y.pub) as b:
            theirs = b.grip()
            assert theirs.cycle_id == 1 and theirs.size.value_mm == pytest.approx(60, abs=3)
            b.release()
    finally:
        waiter.join(90)  # A's wait ends within its event_timeout_s whatever happens
        if not waiter.is_alive():
            a.close()  # an unclosed client's context would block the interpreter's exit
    (got,) = outcome
    assert isinstance(got, DaemonRestarted), got
    assert (got.waited, got.now) == (first, y.instance)
