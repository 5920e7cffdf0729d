"""Deployment: systemd readiness and watchdog (sd_notify), and the unit file.

(Its in-process tests: tests/unit/test_deploy.py.)
"""

from __future__ import annotations

import asyncio
import signal
import socket
from pathlib import Path
from types import SimpleNamespace

import pytest
from fluidsense.controller.cycles.reanalysis import replay_file
from fluidsense.daemon.notify import (
    LoopWatchdog,
    Notifier,
    keep_alive,
    watchdog_interval,
)
from support.harness import run, sim_config


_NOTIFY_SOCKETS: list[socket.socket] = []


def notify_socket(path: Path) -> socket.socket:
    """What systemd listens on: an AF_UNIX datagram socket (closed after the test)."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    _NOTIFY_SOCKETS.append(sock)
    sock.bind(str(path))
    return sock


@pytest.fixture(autouse=True)
def _close_notify_sockets():
    yield
    while _NOTIFY_SOCKETS:
        _NOTIFY_SOCKETS.pop().close()


def receive(sock: socket.socket, timeout_s: float) -> str:
    sock.settimeout(timeout_s)
    try:
        return sock.recv(4096).decode()
    except TimeoutError:
        raise AssertionError(f"no notification within {timeout_s} s") from None


# ------------------------------------------------------------------ sd_notify
def test_the_daemon_notifies_ready_pings_the_watchdog_and_says_stopping(tmp_path, daemon_factory):
    """A real-time daemon with systemd's environment: READY once its sockets are bound and
    samples flow, pings, then on SIGTERM STOPPING, the vented safe state as its last
    message, a closed recording and exit 0. (A SIGTERM during a cycle, which aborts it
    into VENT, is test_zmq's test_real_time_heartbeat_and_sigterm_vents_then_exits.)"""
    sock = notify_socket(tmp_path / "notify")
    cfg = sim_config(tmp_path, clock="realtime")
    d = daemon_factory(cfg, env={"NOTIFY_SOCKET": str(tmp_path / "notify"), "WATCHDOG_USEC": "200000"})
    first = receive(sock, 60)
    assert first.splitlines() == ["READY=1", "STATUS=running: profile pneunet-gripper on sim (real time)"]
    # READY only once both sockets are bound (ipc endpoints are files) and samples flow
    for endpoint in (d.pub, d.cmd):
        assert Path(endpoint.removeprefix("ipc://")).exists()
    d.wait_welcome()
    assert d.request({"cmd": "status"})["samples"] > 0
    assert [receive(sock, 30) for _ in range(5)] == ["WATCHDOG=1"] * 5
    d.proc.send_signal(signal.SIGTERM)
    tail = []
    while not tail or not tail[-1].startswith("STOPPING=1"):
        tail.append(receive(sock, 30))
    assert set(tail[:-1]) <= {"WATCHDOG=1"}
    assert tail[-1].splitlines() == ["STOPPING=1", "STATUS=stopping: venting and closing"]
    while True:
        topic, last = d.next_message(timeout_s=30)
        if topic == "log" and last["message"] == "controller stopped":
            break
    assert last["safe"] is True and last["valves"]  # vented: every valve in its safe position
    assert d.proc.wait(30) == 0
    sock.setblocking(False)
    with pytest.raises(BlockingIOError):  # the daemon has exited: nothing came after STOPPING
        sock.recv(4096)
    sock.close()
    [recording] = (tmp_path / "runs").glob("*.mcap")
    report = asyncio.run(replay_file(recording))
    assert report.closed  # flushed and finished, not cut off (a killed daemon loses up to flush_s)
    assert report.t_last_s == pytest.approx(last["t_s"], abs=0.05)


def test_notifier_reaches_abstract_sockets_and_never_raises(tmp_path):
    name = f"fluidsense-test-{tmp_path.name}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    try:
        note = Notifier(f"@{name}")
        assert note.send("READY=1", "STATUS=up")
        assert receive(sock, 5) == "READY=1\nSTATUS=up"
    finally:
        sock.close()
    # the listener is gone: a failed send is reported, not raised
    assert note.send("WATCHDOG=1") is False
    assert Notifier(str(tmp_path / "nobody")).send("READY=1") is False
    assert Notifier(None).send("READY=1") is False and not Notifier(None).enabled


@pytest.mark.parametrize("env, expected", [
    ({}, None),
    ({"WATCHDOG_USEC": "10000000"}, 10.0),
    ({"WATCHDOG_USEC": "10000000", "WATCHDOG_PID": "4242"}, 10.0),
    ({"WATCHDOG_USEC": "10000000", "WATCHDOG_PID": "4243"}, None),  # someone else's watchdog
    ({"WATCHDOG_USEC": "0"}, None),
    ({"WATCHDOG_USEC": "ten"}, None),
])
def test_watchdog_interval_from_the_environment(env, expected):
    assert watchdog_interval(env, pid=4242) == expected


def test_pings_stop_when_the_loop_stops_progressing(tmp_path):
    """keep_alive with an injected sleep: three periods with blocks, then none."""
    sock = notify_socket(tmp_path / "notify")
    loop = SimpleNamespace(ticks=0, running=True, virtual=False, idle=False)
    periods = []

    async def sleep(period_s):
        periods.append(period_s)
        if len(periods) > 6:
            raise asyncio.CancelledError
        if len(periods) <= 3:
            loop.ticks += 100

    notifier = Notifier(str(tmp_path / "notify"))
    with pytest.raises(asyncio.CancelledError):
        run(keep_alive(notifier, LoopWatchdog(loop), 5.0, sleep=sleep))
    notifier.close()
    got = []
    sock.setblocking(False)
    while True:
        try:
            got.append(sock.recv(64))
        except BlockingIOError:
            break
    assert periods == [5.0] * 7
    assert got == [b"WATCHDOG=1"] * 3


# the unit installed from the wheel as docs/deployment.md says, systemd-analyze verify on it, the
# Dockerfile and the wheel: tests/accept/test_ship.py


def test_a_daemon_started_before_the_robot_is_connecting_then_ready_when_it_comes(tmp_path):
    """The robot PC boots before the robot (or the cable is out): the daemon binds its
    sockets, answers status with 'connecting' and why, tells systemd what it waits for,
    and reports READY only once the box is there and samples flow."""
    from support.harness import Daemon, free_simcell

    sock = notify_socket(tmp_path / "notify")
    quick = {"arm": None, "reconnect": {"first_s": 0.2, "max_s": 0.5, "connect_timeout_s": 5.0}}
    with free_simcell(tmp_path, "modbus", profile="sorting-gripper-quick.yaml", driver=quick) as (box, cell):
        box.network(False)
        d = Daemon(cell, env={"NOTIFY_SOCKET": str(tmp_path / "notify")})
        try:
            d.wait_welcome(ready=False)
            while not (status := d.request({"cmd": "status"}))["connecting"]["error"]:
                assert status["state"] == "connecting"  # the first attempt may still be under way
            assert status["ok"] and status["state"] == "connecting" and "cannot connect" in status["connecting"]["error"]
            refused = d.request({"cmd": "cycle"})
            assert not refused["ok"] and "not connected" in refused["error"]
            waiting = receive(sock, 30)
            assert waiting.startswith("STATUS=connecting to modbus: ")
            box.network(True)
            while (note := receive(sock, 60)).startswith("STATUS=connecting"):
                pass
            assert note.splitlines()[0] == "READY=1"
            assert d.request({"cmd": "status"})["state"] == "idle"
            result = d.request({"cmd": "cycle"})
            assert result["ok"], result
        finally:
            assert d.close() == 0


def test_sigterm_while_connecting_exits_0(tmp_path):
    """Stopping a daemon that is still waiting for its robot: the attempt in progress is
    abandoned (Python 3.11's wait_for could swallow that cancel and retry for ever)."""
    from support.harness import Daemon, free_simcell

    quick = {"arm": None, "reconnect": {"first_s": 0.05, "max_s": 0.1, "connect_timeout_s": 5.0}}
    with free_simcell(tmp_path, "modbus", profile="sorting-gripper-quick.yaml", driver=quick) as (box, cell):
        box.network(False)
        for _ in range(3):  # at different moments of the attempts
            d = Daemon(cell)
            d.wait_welcome(ready=False)
            while d.request({"cmd": "status"})["connecting"]["attempts"] < 3:
                pass
            assert d.close() == 0, d.stderr_now()
