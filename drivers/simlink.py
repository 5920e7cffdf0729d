"""The scene of a simulated cell in another process (``fluidsense simcell``), reached
through its sim control port: lay out objects, read the truth. Only used when a cell
config names a ``sim_control_port``; a real cell has no such thing."""

from __future__ import annotations

import asyncio
import json
from typing import Any

from fluidsense.common.errors import (
    DeviceTimeoutError,
    DriverError,
    LinkLostError,
    NotSupportedError,
)
from fluidsense.drivers.base import SceneControl


class RemoteScene(SceneControl):
    def __init__(self, host: str, port: int, timeout_s: float = 5.0):
        super().__init__("sim-control")
        self.host, self.port, self.timeout_s = host, port, timeout_s
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._lock = asyncio.Lock()

    async def _setup(self) -> None:
        try:
            self._reader, self._writer = await asyncio.wait_for(
                asyncio.open_connection(self.host, self.port, limit=1 << 22), self.timeout_s)
        except (OSError, asyncio.TimeoutError) as exc:
            raise LinkLostError(f"sim control {self.host}:{self.port}: {exc or 'no answer'}") from exc

    async def _stop(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._reader = self._writer = None

    async def request(self, payload: dict[str, Any]) -> dict[str, Any]:
        self._require_connected()
        async with self._lock:  # one request at a time: replies come in order
            try:
                self._writer.write((json.dumps(payload) + "\n").encode())
                line = await asyncio.wait_for(self._reader.readline(), self.timeout_s)
            except asyncio.TimeoutError as exc:
                raise DeviceTimeoutError(f"sim control: no reply to {payload['cmd']}") from exc
            except OSError as exc:
                raise LinkLostError(f"sim control: {exc}") from exc
        if not line:
            raise LinkLostError("sim control: the simulated cell closed the connection")
        reply = json.loads(line)
        if not reply.get("ok"):
            raise DriverError(f"sim control refused {payload['cmd']}: {reply.get('error')}")
        return reply

    async def set_scene(self, scene: Any, t: float) -> None:
        await self.request({"cmd": "scene", "scene": scene.model_dump(mode="json")})

    async def set_world(self, world: Any, t: float) -> None:
        await self.request({"cmd": "world", "world": world.model_dump(mode="json")})

    def truth(self) -> dict[str, Any]:
        raise NotSupportedError("the simulated cell is in another process: use read_truth()")

    async def read_truth(self) -> dict[str, Any]:
        return (await self.request({"cmd": "truth"}))["truth"]
