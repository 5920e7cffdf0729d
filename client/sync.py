"""The blocking client: ``Gripper(cmd_endpoint, pub_endpoint)``. Its calls are the core's
(core.Session: status, grip, measure, release, abort, reset, scene, request, attach,
next_event, wait_for), each run here by blocking on the sockets."""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator
from typing import Any

import zmq
from fluidsense.common.names import GRIPPER_TOPICS

from ._sockets import Sockets
from .core import CALLS, Call, Exchange, Listen, Session, face_signature
from .types import NoWelcome, typed


class Gripper(Sockets):
    def __init__(self, cmd: str = "tcp://127.0.0.1:5561", pub: str | None = "tcp://127.0.0.1:5560", *,
                 timeout_s: float = 10.0, event_timeout_s: float = 120.0, curve: tuple[str, str] | None = None,
                 topics: tuple[str, ...] = (*GRIPPER_TOPICS, "fault"), context: zmq.Context | None = None):
        """``timeout_s``: for a reply; ``event_timeout_s``: for an event (a grip's grasp
        comes after charging and the measurement windows: tens of seconds on some
        profiles); ``curve``: (client secret key file, server public key file); ``pub``
        None: requests only; ``context``: a ZeroMQ context to share (else its own)."""
        super().__init__(Session(cmd, pub, timeout_s, event_timeout_s), context or zmq.Context(), context is None,
                         curve, topics)

    def _run(self, call: Call[Any]) -> Any:
        try:
            step = next(call)
            while True:
                step = call.send(self._do(step))
        except StopIteration as end:
            return end.value
        except NoWelcome as exc:
            better = self._explained(exc)
            if better is exc:
                raise
            raise better from exc

    def _do(self, step: Exchange | Listen) -> Any:
        if isinstance(step, Listen):
            wait = -1 if step.timeout_s is None else int(1000 * step.timeout_s)
            return self._sub.recv_multipart() if self._sub.poll(wait) else None
        req = self._request_socket()
        req.send(step.body)
        if req.poll(int(1000 * step.timeout_s)):
            return req.recv()
        self._drop_request_socket()
        return None

    def events(self, timeout_s: float | None = None) -> Iterator[Any]:
        """Typed events (Grasp, Contact, Slip, Released; Event for other topics) until
        ``timeout_s`` passes without one."""
        while (ev := self.next_event(timeout_s)) is not None:
            yield typed(ev)

    def __enter__(self) -> Gripper:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _blocking(call: Callable[..., Call[Any]]) -> Callable[..., Any]:
    @functools.wraps(call)
    def method(self: Gripper, *args: Any, **kwargs: Any) -> Any:
        return self._run(call(self._session, *args, **kwargs))

    method.__signature__ = face_signature(call)
    return method


for _name in CALLS:
    setattr(Gripper, _name, _blocking(getattr(Session, _name)))
