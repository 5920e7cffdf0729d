"""The asyncio client: ``AsyncGripper(cmd_endpoint, pub_endpoint)``, the same calls as
``Gripper`` (the core's, core.Session), awaited."""

from __future__ import annotations

import asyncio
import functools
from collections.abc import AsyncIterator, Callable
from typing import Any

import zmq.asyncio
from fluidsense.common.names import GRIPPER_TOPICS

from ._sockets import Sockets
from .core import CALLS, Call, Exchange, Listen, Session, face_signature
from .types import NoWelcome, typed


class AsyncGripper(Sockets):
    def __init__(self, cmd: str = "tcp://127.0.0.1:5561", pub: str | None = "tcp://127.0.0.1:5560", *,
                 timeout_s: float = 10.0, event_timeout_s: float = 120.0, curve: tuple[str, str] | None = None,
                 topics: tuple[str, ...] = (*GRIPPER_TOPICS, "fault"), context: zmq.asyncio.Context | None = None):
        super().__init__(Session(cmd, pub, timeout_s, event_timeout_s), context or zmq.asyncio.Context(),
                         context is None, curve, topics)
        self._lock = asyncio.Lock()  # one exchange at a time on the REQ socket

    async def _run(self, call: Call[Any]) -> Any:
        try:
            step = next(call)
            while True:
                step = call.send(await self._do(step))
        except StopIteration as end:
            return end.value
        except NoWelcome as exc:
            better = self._explained(exc)
            if better is exc:
                raise
            raise better from exc

    async def _do(self, step: Exchange | Listen) -> Any:
        if isinstance(step, Listen):
            wait = None if step.timeout_s is None else int(1000 * step.timeout_s)
            return await self._sub.recv_multipart() if await self._sub.poll(wait) else None
        async with self._lock:
            req = self._request_socket()
            await req.send(step.body)
            if await req.poll(int(1000 * step.timeout_s)):
                return await req.recv()
            self._drop_request_socket()
            return None

    async def events(self, timeout_s: float | None = None) -> AsyncIterator[Any]:
        """Typed events until ``timeout_s`` passes without one."""
        while (ev := await self.next_event(timeout_s)) is not None:
            yield typed(ev)

    async def __aenter__(self) -> AsyncGripper:
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.close()


def _awaited(call: Callable[..., Call[Any]]) -> Callable[..., Any]:
    @functools.wraps(call)
    async def method(self: AsyncGripper, *args: Any, **kwargs: Any) -> Any:
        return await self._run(call(self._session, *args, **kwargs))

    method.__signature__ = face_signature(call)
    return method


for _name in CALLS:
    setattr(AsyncGripper, _name, _awaited(getattr(Session, _name)))
