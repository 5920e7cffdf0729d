"""All servers of one emulated control box on one asyncio loop, and the controller cycle
that drives them.

Run it in its own process (``python -m fluidsense.simulator.controlbox``): ur_rtde's
constructors hold the GIL while they wait for the robot, so an emulator thread in the
client's process would never get to answer.
"""

from __future__ import annotations

import asyncio
import logging

from fluidsense.common.errors import DriverError
from fluidsense.simulator.controlbox.box import ControlBox
from fluidsense.simulator.controlbox.config import ControlBoxConfig
from fluidsense.simulator.controlbox.dashboard import DashboardServer
from fluidsense.simulator.controlbox.modbus import ModbusServer
from fluidsense.simulator.controlbox.model import ControlBoxModel
from fluidsense.simulator.controlbox.rtde import RtdeServer
from fluidsense.simulator.controlbox.scriptport import ScriptServer

log = logging.getLogger(__name__)


class Emulator:
    """``await start()``, then ``await run()`` until ``stop()``; ``close()`` at the end."""

    def __init__(self, config: ControlBoxConfig, model: ControlBoxModel):
        self.config = config
        loop = asyncio.get_running_loop()
        self.box = ControlBox(config, model, clock=loop.time)
        self.box.shutdown_requested = self.stop
        host = config.host
        self.rtde = RtdeServer(self.box, host, config.rtde_port)
        self.servers = [
            self.rtde,
            DashboardServer(self.box, host, config.dashboard_port),
            ScriptServer(self.box, host, config.script_port),
            ModbusServer(self.box, host, config.modbus_port),
        ]
        self._stop = asyncio.Event()
        self._started: list = []
        self.box.network_requested = self.set_network
        self._network: asyncio.Task | None = None

    async def start(self) -> None:
        """Listen on every port; raises DriverError naming the one that failed."""
        for server in self.servers:
            try:
                await server.start()
            except (OSError, RuntimeError) as exc:
                await self.close()
                raise DriverError(f"{type(server).__name__} cannot listen on "
                                  f"{server.host}:{server.port}: {exc}") from exc
            self._started.append(server)
        log.info("control box emulator listening on %s", self.config.host)

    def stop(self) -> None:
        self._stop.set()

    def set_network(self, up: bool) -> None:
        """A pulled (or plugged) cable: every robot port closes (or listens again); the
        box, its program and its outputs carry on either way."""
        if up == self.box.network_up:
            return
        self.box.network_up = up
        log.warning("network %s", "up: listening again" if up else "down: every port closed")
        previous = self._network

        async def change() -> None:
            if previous is not None:
                await previous
            if up:
                await self.start()
            else:
                await self.close()

        self._network = asyncio.get_running_loop().create_task(change())

    async def run(self) -> None:
        """The controller cycle at the control rate, until ``stop()``."""
        loop = asyncio.get_running_loop()
        period = 1.0 / self.config.control_hz
        deadline = loop.time()
        while not self._stop.is_set():
            self.box.tick()
            self.rtde.tick()
            deadline += period
            delay = deadline - loop.time()
            if delay < -period:
                deadline = loop.time()  # fell behind (loaded machine): skip, never burst
            await asyncio.sleep(max(0.0, delay))

    async def close(self) -> None:
        for server in reversed(self._started):
            try:
                await server.close()
            except Exception as exc:  # noqa: BLE001 - close the others anyway
                log.error("closing %s failed: %s", type(server).__name__, exc)
        self._started.clear()
