"""The safety latch: whatever fails inside the service, the cell ends vented (as the
device reports), the fault is latched and published, and nobody is left waiting.

(Its in-process tests: tests/unit/test_safety_latch.py.)
"""

from __future__ import annotations

import asyncio

import pytest
from fluidsense.controller.config import CellConfig, load_cell_config
from fluidsense.controller.service import Controller
from fluidsense.drivers.registry import build_backend
from support.harness import sim_config

#: a hang fails the test instead of the suite; nothing below waits on wall time otherwise
HANG_S = 60.0


class Boom(RuntimeError):
    pass


def _daemon_cfg(tmp_path) -> CellConfig:
    return load_cell_config(sim_config(tmp_path, clock="realtime"))


def test_a_sample_loop_that_dies_stops_the_daemon_vented_with_status_1(tmp_path, monkeypatch):
    """The loop's own guard fails too (the latch itself raises): the loop task ends, and
    the daemon must notice, vent on the way out and exit 1 for systemd to restart it."""
    from fluidsense.controller.safety.latch import SafetyLatch
    from fluidsense.daemon import app

    built = {}

    def build(cfg, hw):
        built["backend"] = backend = build_backend(cfg, hw)
        return backend

    async def broken_block(self, block):
        self.now = block.t_end
        if self.now > 0.2:
            await self.backend.valves.set("actuate", True, self.now)  # inflate, then the bug
            raise Boom("injected in the loop")

    async def broken_trip(self, fault, now):
        raise Boom("injected in the latch")

    monkeypatch.setattr(app, "build_backend", build)
    monkeypatch.setattr(Controller, "on_block", broken_block)
    monkeypatch.setattr(SafetyLatch, "trip", broken_trip)
    code = asyncio.run(asyncio.wait_for(app.run_daemon(_daemon_cfg(tmp_path)), HANG_S))
    cell = built["backend"].sim
    assert code == 1
    assert cell.outputs == built["backend"].valves.safe_positions  # vented on the way out


def test_a_command_socket_that_dies_stops_the_daemon_with_status_1(tmp_path, monkeypatch):
    from fluidsense.controller.requests.server import CommandServer
    from fluidsense.daemon import app

    async def broken_serve(self, answer):
        await asyncio.sleep(0)
        raise Boom("injected in the command socket")

    monkeypatch.setattr(CommandServer, "serve", broken_serve)
    code = asyncio.run(asyncio.wait_for(app.run_daemon(_daemon_cfg(tmp_path)), HANG_S))
    assert code == 1


@pytest.mark.parametrize("state", ["idle", "actuating", "faulted", "starved"])
def test_sigterm_ends_the_daemon_vented_in_every_state(state, tmp_path, monkeypatch):
    """SIGTERM in each state: the daemon vents and returns 0. ``starved``: every block
    takes longer to handle than it lasts, so the loop is always behind its source (before
    the loop yielded each block, signals then waited for ever)."""
    import os
    import signal
    import time as _time

    from fluidsense.daemon import app

    built = {}

    def build(cfg, hw):
        built["backend"] = backend = build_backend(cfg, hw)
        return backend

    monkeypatch.setattr(app, "build_backend", build)
    if state == "starved":
        real = Controller.on_block

        async def slow(self, block):
            _time.sleep(0.012)  # deliberately blocks the loop longer than a 10 ms block lasts
            await real(self, block)

        monkeypatch.setattr(Controller, "on_block", slow)

    async def main():
        daemon = asyncio.ensure_future(app.run_daemon(_daemon_cfg(tmp_path)))
        while "backend" not in built or not built["backend"].source.connected:
            await asyncio.sleep(0.01)  # polling start-up, bounded by HANG_S below
        backend = built["backend"]
        cell = backend.sim
        if state == "actuating":
            backend.valves._state["actuate"] = True  # as a cycle leaves it, without running one
            cell.command_valve("actuate", True, cell.t_last)
        elif state == "faulted":
            cell.inject("sensor_nan", cell.t_next)
        while not (state != "faulted" or cell.outputs == backend.valves.safe_positions) or cell.t_next < 0.5:
            await asyncio.sleep(0.01)
        os.kill(os.getpid(), signal.SIGTERM)
        return await asyncio.wait_for(daemon, HANG_S), cell.outputs, backend.valves.safe_positions

    code, outputs, safe = asyncio.run(main())
    assert code == 0 and outputs == safe
