"""The daemon as a gripper: grip, hold, slip, release and measure over real sockets, driven
through the client library (fluidsense.client), every event checked against
docs/zmq-schema.md. Virtual time on the simulated cell with the pneunet gripper and the
shipped calibration (config/calibrations/pneunet-gripper-p_eq.json)."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
from fluidsense.client import AsyncGripper, GripEnded, Gripper, Refused
from fluidsense.controller.requests.grip_watch import SlipWatch
from support.configs import cell_config
from support.gripper import grip_a_60_mm_cylinder, slip_to_40_mm
from support.harness import REPO, ipc_endpoints, sim_config

CALIBRATION = REPO / "config" / "calibrations" / "pneunet-gripper-p_eq.json"


def gripper_config(tmp_path, calibrated: bool = True, **gripper):
    return sim_config(tmp_path, clock="virtual",
                      gripper={"calibrations": [str(CALIBRATION)] if calibrated else [], **gripper})








def _slip_blocks(tau_s: float, stall_s: float, seed: int):
    """Block means (t, Pa) of a held grip that slips at t = 1 s, shaped as the simulated
    pneunet gripper's recording of the 60 -> 40 mm slip (held 36.62 kPa, a dip to 34.85,
    back to 35.78 with a time constant ``tau_s``, about 0.12 s there), 10 ms blocks with
    the sensor's noise. ``stall_s``: the stream stalls 30 ms after the slip and its backlog
    arrives that much later (as ur_rtde's receive thread starved on a busy PC)."""
    rng = np.random.default_rng(seed)
    held, dip, settled = 36.62e3, 34.85e3, 35.78e3
    t = np.arange(0.0, 3.0, 0.01)
    p = np.where(t < 1.0, held, settled - (settled - dip) * np.exp(-(t - 1.0) / tau_s))
    p = p + rng.normal(0, 30.0, t.size)  # a 10-sample mean of 0.1 kPa noise
    stamped = np.where(t < 1.03, t, t + stall_s)
    return list(zip(stamped, p)), settled


@pytest.mark.parametrize("tau_s, stall_s", [(0.12, 0.0), (0.12, 0.3), (0.3, 0.3)])
def test_a_slip_is_reported_at_the_level_it_settles_at_even_across_a_stalled_stream(tau_s, stall_s):
    """The slip's level gives the new size (0.04 kPa per mm on the shipped calibration):
    it must be the settled level, not the bottom of the dip. Two faults of the first
    version: with the sensor's noise its 'steady' (the range of the block means below a
    third of the drop) was rarely true, so a slip waited for the 5 s fallback; and across
    a stall, the dip's samples arriving late made a flat stretch of the gap, and the slip
    was reported at the dip (a size below the calibrated range, seen in CI through the ur
    driver; 0.8 kPa low here with the slower recovery)."""
    for seed in range(10):  # the noise decides when a flat stretch shows: ten draws of it
        blocks, settled = _slip_blocks(tau_s, stall_s, seed)
        watch = SlipWatch(drop_pa=300.0, within_s=0.5, sign=1.0, level_pa=36.62e3)
        reports = [(t, r) for t, p in blocks if (r := watch.feed(t, p)) is not None]
        assert len(reports) == 1, (seed, reports)
        ((reported_at, slip),) = reports
        assert slip["at_s"] == pytest.approx(1.0, abs=0.03), seed
        assert reported_at < 1.0 + stall_s + 1.5, seed  # settled, not the 10 x within_s fallback
        assert slip["level_pa"] == pytest.approx(settled, abs=60.0), seed  # 1.5 mm
        assert slip["drop_pa"] == pytest.approx(36.62e3 - settled, abs=60.0), seed


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


def test_a_calibration_of_another_profile_stops_the_daemon_before_it_starts(tmp_path):
    import json
    import subprocess
    import sys

    other = json.loads(CALIBRATION.read_text()) | {"profile": "sorting-gripper"}
    (tmp_path / "other.json").write_text(json.dumps(other))
    path = gripper_config(tmp_path, calibrations=["other.json"])  # relative to the cell config
    out = subprocess.run([sys.executable, "-m", "fluidsense", "run", "--config", str(path)], cwd=REPO,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert f"{path}: gripper.calibrations.0: " in out.stderr and "calibrates profile 'sorting-gripper'" in out.stderr


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
