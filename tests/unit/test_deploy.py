"""Deployment: systemd readiness and watchdog (sd_notify), and the unit file.

(Its tests with real peers: tests/system/test_deploy.py.)
"""

from __future__ import annotations

import asyncio
import shlex
import socket
from types import SimpleNamespace

import pytest
from fluidsense.daemon.notify import LoopWatchdog, Notifier
from support.shipping import unit_entries


_NOTIFY_SOCKETS: list[socket.socket] = []


@pytest.fixture(autouse=True)
def _close_notify_sockets():
    yield
    while _NOTIFY_SOCKETS:
        _NOTIFY_SOCKETS.pop().close()


def test_the_ping_period_is_half_the_watchdog_timeout(tmp_path):
    env = {"NOTIFY_SOCKET": str(tmp_path / "notify"), "WATCHDOG_USEC": "10000000"}
    assert Notifier.from_env(env).ping_period_s == 5.0
    assert Notifier.from_env({**env, "WATCHDOG_USEC": "0"}).ping_period_s is None
    assert Notifier.from_env({"WATCHDOG_USEC": "10000000"}).ping_period_s is None  # nobody to ping


# --------------------------------------------------------------- the watchdog
def test_watchdog_logic():
    loop = SimpleNamespace(ticks=0, running=True, virtual=False, idle=False)
    dog = LoopWatchdog(loop)
    assert not dog.alive()  # real time, no block since the last look
    loop.ticks += 1
    assert dog.alive() and not dog.stalled
    assert not dog.alive() and dog.stalled
    loop.ticks += 5
    assert dog.alive() and not dog.stalled
    loop.virtual, loop.idle = True, True  # parked, nothing waits on samples: time stands still
    assert dog.alive() and dog.alive()
    loop.idle = False  # something waits on samples and none come: stalled
    assert not dog.alive()
    loop.ticks += 1
    loop.running = False  # the loop task ended
    assert not dog.alive()


def test_a_stalled_sample_loop_fails_the_watchdog(virtual_controller):
    """A real controller in virtual time: idle is alive; a read that never returns while a
    cycle waits on samples, or a valve command that never returns, is a stall."""

    async def body(ctrl):
        dog = LoopWatchdog(ctrl.loop)
        await asyncio.sleep(0)
        idle = [dog.alive(), dog.alive()]
        await ctrl.run_cycle()
        after_cycle = dog.alive()

        source = ctrl.backend.source
        real_read, stuck, never = source.read_block, asyncio.Event(), asyncio.Event()
        reads = 0

        async def read_block():
            nonlocal reads
            reads += 1
            if reads > 500:  # 5 s into the cycle
                stuck.set()
                await never.wait()
            return await real_read()

        source.read_block = read_block
        fut = await ctrl.start_cycle()
        await stuck.wait()
        stalled_read = [dog.alive(), dog.alive()]
        fut.cancel()
        return idle, after_cycle, stalled_read

    idle, after_cycle, stalled_read = virtual_controller(body)
    assert idle == [True, True]
    assert after_cycle is True
    assert stalled_read == [True, False]  # progress before the stall, then none


def test_a_loop_stuck_in_a_device_command_fails_the_watchdog(virtual_controller):
    async def body(ctrl):
        dog = LoopWatchdog(ctrl.loop)
        valves = ctrl.backend.valves
        real_set, stuck, never = valves.set, asyncio.Event(), asyncio.Event()

        async def set_valve(valve, open_, t):
            if valve == "actuate" and open_:  # the sequencer opens it from inside the loop
                stuck.set()
                await never.wait()
            return await real_set(valve, open_, t)

        valves.set = set_valve
        fut = await ctrl.start_cycle()
        await stuck.wait()
        verdicts = [dog.alive(), dog.alive()]
        fut.cancel()
        return verdicts

    assert virtual_controller(body) == [True, False]


# ------------------------------------------------------------------ the unit
def test_the_systemd_unit_is_a_notify_service_with_a_watchdog():
    unit = unit_entries()
    one = {k: v[-1] for k, v in unit.items()}
    assert one["Service.Type"] == "notify" and one["Service.NotifyAccess"] == "main"
    assert one["Service.Restart"] == "on-failure" and one["Service.KillSignal"] == "SIGTERM"
    assert one["Service.KillMode"] == "mixed"  # SIGTERM to the daemon only: it stops its sampler itself
    # the loop can go no_data_s (0.5 s) plus a 1 s retry pause between iterations while
    # a device is down: a ping period (half WatchdogSec) must cover that
    watchdog_s = float(one["Service.WatchdogSec"].removesuffix("s"))
    assert watchdog_s / 2 > 0.5 + 1.0
    assert float(one["Service.TimeoutStopSec"].removesuffix("s")) > 5
    assert one["Service.User"] != "root" and one["Service.NoNewPrivileges"] == "yes"
    # read-only but for its state directory, where it works and records
    assert one["Service.ProtectSystem"] == "strict" and one["Service.StateDirectory"] == "fluidsense"
    assert one["Service.WorkingDirectory"] == "/var/lib/fluidsense"
    assert one["Service.LimitRTPRIO"] == "40"  # the sampler's SCHED_FIFO priority (docs/sampler.md)
    argv = shlex.split(one["Service.ExecStart"])
    assert argv[0] == "/opt/fluidsense/venv/bin/fluidsense"  # the venv the wheel is installed into
    assert argv[1:] == ["run", "--config", "/etc/fluidsense/cell.yaml", "--tasks-dir", "/etc/fluidsense/tasks"]
