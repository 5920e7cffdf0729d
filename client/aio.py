"""The asyncio client: ``AsyncGripper(cmd_endpoint, pub_endpoint)``, the same calls as
``Gripper``, awaited."""

from __future__ import annotations

import asyncio
import json
from collections import deque
from collections.abc import AsyncIterator
from typing import Any

import zmq
import zmq.asyncio

from . import _sockets as S
from .types import (
    GRIPPER_TOPICS,
    Event,
    Grasp,
    GripEnded,
    NoReply,
    Refused,
    Released,
    typed,
)


class AsyncGripper:
    def __init__(self, cmd: str = "tcp://127.0.0.1:5561", pub: str = "tcp://127.0.0.1:5560", *,
                 timeout_s: float = 10.0, event_timeout_s: float = 120.0, curve: tuple[str, str] | None = None,
                 topics: tuple[str, ...] = (*GRIPPER_TOPICS, "fault")):
        self.cmd_endpoint, self.pub_endpoint = cmd, pub
        self.timeout_s, self.event_timeout_s = timeout_s, event_timeout_s
        self._keys = S.curve_keys(curve)
        self._ctx = zmq.asyncio.Context()
        self._req: zmq.asyncio.Socket | None = None
        self._sub = S.setup_sub(self._ctx.socket(zmq.SUB), pub, topics)
        self._pending: deque[Event] = deque(maxlen=10_000)
        self._attached = False
        self._lock = asyncio.Lock()  # one request at a time on the REQ socket

    async def request(self, body: dict[str, Any], timeout_s: float | None = None) -> dict[str, Any]:
        await self.attach()
        async with self._lock:
            if self._req is None:
                self._req = S.setup_req(self._ctx.socket(zmq.REQ), self.cmd_endpoint, self._keys)
            await self._req.send(json.dumps(body).encode())
            if not await self._req.poll(int(1000 * (self.timeout_s if timeout_s is None else timeout_s))):
                self._req.close()
                self._req = None
                raise NoReply(f"no reply to {body.get('cmd')!r} from {self.cmd_endpoint}")
            reply = json.loads(await self._req.recv())
        if not reply.get("ok"):
            raise Refused(body, reply)
        return reply

    async def status(self) -> dict[str, Any]:
        return await self.request({"cmd": "status"})

    async def grip(self, p0_kpa: float | None = None, timeout_s: float | None = None, label: str | None = None,
                   wait: bool = True) -> Grasp | int:
        reply = await self.request(S.request_body("grip", p0_kpa=p0_kpa, timeout_s=timeout_s, label=label))
        if not wait:
            return reply["cycle_id"]
        limit = self.event_timeout_s if timeout_s is None else timeout_s + self.timeout_s
        return Grasp.of(await self.wait_for("grasp", reply["cycle_id"], limit, fail_on_end=True))

    async def measure(self, p0_kpa: float | None = None, label: str | None = None, store_reference: bool = False,
                      wait: bool = True) -> Grasp | int:
        reply = await self.request(S.request_body("measure", p0_kpa=p0_kpa, label=label,
                                                  store_reference=store_reference or None))
        if not wait:
            return reply["cycle_id"]
        grasp = Grasp.of(await self.wait_for("grasp", reply["cycle_id"], self.event_timeout_s, fail_on_end=True))
        await self.wait_for("released", reply["cycle_id"], self.event_timeout_s)
        return grasp

    async def release(self, wait: bool = True) -> Released | int:
        reply = await self.request({"cmd": "release"})
        if not wait:
            return reply["cycle_id"]
        return Released.of(await self.wait_for("released", reply["cycle_id"], self.event_timeout_s))

    async def abort(self, reason: str = "client") -> bool:
        return (await self.request({"cmd": "abort", "reason": reason}))["aborted"]

    async def reset(self) -> str:
        return (await self.request({"cmd": "reset"}))["state"]

    async def scene(self, scene: dict[str, Any]) -> dict[str, Any]:
        return (await self.request({"cmd": "scene", "scene": scene}))["scene"]

    # ------------------------------------------------------------------ events
    async def attach(self, timeout_s: float | None = None) -> None:
        limit = self.timeout_s if timeout_s is None else timeout_s
        try:
            async with asyncio.timeout(limit):
                while not self._attached:
                    self._take(await self._sub.recv_multipart())
        except TimeoutError:
            raise NoReply(f"no welcome from {self.pub_endpoint}: is the daemon running?") from None

    def _take(self, frames: list[bytes]) -> Event | None:
        if frames == [S.WELCOME]:
            self._attached = True
            return None
        return S.decode(frames)

    async def next_event(self, timeout_s: float | None = None) -> Event | None:
        if self._pending:
            return self._pending.popleft()
        try:
            async with asyncio.timeout(timeout_s):
                while True:
                    ev = self._take(await self._sub.recv_multipart())
                    if ev is not None:
                        return ev
        except TimeoutError:
            return None

    async def events(self, timeout_s: float | None = None) -> AsyncIterator[Any]:
        while (ev := await self.next_event(timeout_s)) is not None:
            yield typed(ev)

    async def wait_for(self, topic: str, cycle_id: int | None, timeout_s: float, fail_on_end: bool = False) -> Event:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        skipped: list[Event] = []
        try:
            while True:
                ev = await self.next_event(max(0.0, deadline - loop.time()))
                if ev is None:
                    raise NoReply(f"no {topic} of cycle {cycle_id} within {timeout_s:g} s")
                if S.matches(ev, topic, cycle_id):
                    return ev
                skipped.append(ev)
                if fail_on_end and S.matches(ev, "released", cycle_id):
                    raise GripEnded(Released.of(ev))
        finally:
            self._pending.extendleft(reversed(skipped))

    def close(self) -> None:
        if self._req is not None:
            self._req.close()
        self._sub.close()
        self._ctx.term()

    async def __aenter__(self) -> AsyncGripper:
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.close()
