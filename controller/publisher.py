"""ZeroMQ PUB side of the published interface (schema in docs/zmq-schema.md).

Every message is two frames: the topic (ASCII) and a JSON object that always carries
``schema`` (the schema version), ``topic``, ``seq`` (one counter over all topics, so a
subscriber sees gaps) and ``t_s`` (sample time of the newest sample when it was sent).
A slow subscriber never blocks the controller: PUB drops at its high-water mark and the
drop is counted.

The socket is an XPUB with a welcome message: a subscriber that subscribes to ``hello``
receives the single frame ``hello`` as soon as it is connected, so it knows that nothing
published after that is lost to the usual ZeroMQ slow-joiner gap.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
from typing import Any

import numpy as np
import zmq

log = logging.getLogger(__name__)

SCHEMA_VERSION = 1
TOPICS = ("pressure", "state", "cycle", "heartbeat", "fault", "task", "log")
WELCOME = b"hello"


def _default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def _clean(obj: Any) -> Any:
    """JSON has no NaN/inf: they become null."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    return obj


def encode(topic: str, seq: int, t_s: float, payload: dict[str, Any]) -> list[bytes]:
    msg = {"schema": SCHEMA_VERSION, "topic": topic, "seq": seq, "t_s": t_s, **payload}
    return [topic.encode("ascii"), json.dumps(_clean(msg), default=_default, allow_nan=False).encode()]


class Publisher:
    def __init__(self, endpoint: str, context: zmq.Context | None = None, hwm: int = 10_000):
        self.endpoint = endpoint
        self._ctx = context or zmq.Context.instance()
        self._sock = self._ctx.socket(zmq.XPUB)
        self._sock.setsockopt(zmq.SNDHWM, hwm)
        self._sock.setsockopt(zmq.LINGER, 1000)
        self._sock.setsockopt(zmq.XPUB_WELCOME_MSG, WELCOME)
        self._sock.bind(endpoint)
        self.seq = 0
        self.dropped = 0
        self.subscriptions = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        try:
            self._loop = asyncio.get_running_loop()
            self._loop.add_reader(self._sock.getsockopt(zmq.FD), self._service)
        except RuntimeError:  # no event loop: serviced on every send only
            self._loop = None
        log.info("publishing on %s", endpoint)

    def _service(self) -> None:
        """Read subscription frames. libzmq attaches new subscribers (and sends them the
        welcome) only while the application services the socket, so this runs whenever
        its file descriptor is readable (edge-triggered: drain until empty)."""
        while self._sock.getsockopt(zmq.EVENTS) & zmq.POLLIN:
            try:
                frame = self._sock.recv(zmq.NOBLOCK)
            except zmq.Again:
                break
            if frame[:1] == b"\x01":
                self.subscriptions += 1
            elif frame[:1] == b"\x00":
                self.subscriptions = max(0, self.subscriptions - 1)

    def send(self, topic: str, t_s: float, payload: dict[str, Any]) -> None:
        self.seq += 1
        try:
            self._sock.send_multipart(encode(topic, self.seq, t_s, payload), flags=zmq.NOBLOCK)
        except zmq.Again:
            self.dropped += 1
        self._service()

    def close(self) -> None:
        if self._loop is not None and not self._loop.is_closed():
            self._loop.remove_reader(self._sock.getsockopt(zmq.FD))
        self._sock.close()


class NullPublisher:
    """Used when nothing is published (demo, benchmarks): same interface, no socket."""

    endpoint = None

    def __init__(self) -> None:
        self.seq = 0
        self.dropped = 0

    def send(self, topic: str, t_s: float, payload: dict[str, Any]) -> None:
        self.seq += 1

    def close(self) -> None:
        return None
