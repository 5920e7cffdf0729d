"""ZeroMQ PUB side of the published interface (schema in docs/zmq-schema.md).

Every message is two frames: the topic (ASCII) and a JSON object that always carries
``schema`` (the schema version), ``topic``, ``seq`` (one counter over all topics, so a
subscriber sees gaps) and ``t_s`` (sample time of the newest sample when it was sent).
A slow subscriber never blocks the controller: PUB drops at its high-water mark and the
drop is counted.

The socket is an XPUB with a welcome message: a subscriber that subscribes to ``hello``
receives the single frame ``hello`` as soon as it is connected, so it knows that nothing
published after that is lost to the usual ZeroMQ slow-joiner gap.

Subscriptions are untrusted input. libzmq keeps each subscription prefix in a trie of
about 50 bytes per byte of prefix, for as long as its subscriber stays connected: one
8 MB subscription cost 880 MB. So a subscription frame is limited to
MAX_SUBSCRIPTION_BYTES (a larger frame drops that connection), and the trie is bounded by
counting what does not belong in it: subscriptions that match none of our topics (no
topic starts with them) and frames that are not subscriptions at all. Once there were
SUBSCRIPTION_BUDGET of them, every subscriber connection is dropped (the socket unbinds
and binds again), which frees the trie; well-behaved subscribers reconnect by themselves
and get the welcome again. XPUB_MANUAL does not bound it: libzmq 4.3 still keeps every
subscription a peer sends, in a second trie, to unsubscribe it when the peer leaves.
Matching stays ZeroMQ's own: a prefix gets every topic that starts with it.
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
KNOWN = tuple(t.encode() for t in TOPICS) + (WELCOME,)
# a frame's size limit also applies to the ZMTP handshake (a subscriber's READY command is
# about 30 bytes; other ZeroMQ libraries may add properties)
MAX_SUBSCRIPTION_BYTES = 256
SUBSCRIPTION_BUDGET = 500  # foreign frames between connection resets: a few MB of trie at most
RCVHWM = 64  # subscription frames queued per subscriber before libzmq stops reading it
SERVICE_BATCH = 256  # frames read per turn of the event loop
REBIND_RETRY_S = 0.02


def is_known_prefix(prefix: bytes) -> bool:
    """Whether a subscription to ``prefix`` receives any of our messages."""
    return any(name.startswith(prefix) for name in KNOWN)


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
        self._sock.setsockopt(zmq.RCVHWM, RCVHWM)
        self._sock.setsockopt(zmq.MAXMSGSIZE, MAX_SUBSCRIPTION_BYTES)
        self._sock.setsockopt(zmq.LINGER, 1000)
        self._sock.setsockopt(zmq.XPUB_WELCOME_MSG, WELCOME)
        try:
            self._sock.bind(endpoint)
        except zmq.ZMQError:
            self._sock.close(linger=0)
            raise
        self._bound = self._sock.getsockopt_string(zmq.LAST_ENDPOINT)  # tcp://localhost:N -> 127.0.0.1
        self.seq = 0
        self.dropped = 0
        self.subscriptions = 0  # distinct prefixes of our topics subscribed to
        self.foreign = 0  # foreign frames since the last reset
        self.resets = 0
        self._rebinding = False
        self._more_scheduled = False
        self._closed = False
        self._loop: asyncio.AbstractEventLoop | None = None
        try:
            self._loop = asyncio.get_running_loop()
            self._loop.add_reader(self._sock.getsockopt(zmq.FD), self._service)
        except RuntimeError:  # no event loop: serviced on every send only
            self._loop = None
        log.info("publishing on %s", endpoint)

    @property
    def stats(self) -> dict[str, int]:
        return {"dropped": self.dropped, "subscriptions": self.subscriptions,
                "foreign_subscriptions": self.foreign, "subscriber_resets": self.resets}

    def _service(self) -> None:
        """Read subscription frames. libzmq attaches new subscribers (and sends them the
        welcome) only while the application services the socket, so this runs whenever
        its file descriptor is readable (edge-triggered: drain until empty). A flood is
        read a batch per turn of the event loop, so that the sample loop keeps its turns."""
        if self._closed:
            return
        for _ in range(SERVICE_BATCH):
            try:
                frame = self._sock.recv(zmq.NOBLOCK)
            except zmq.Again:
                return
            self._account(frame)
        if self._loop is not None and not self._more_scheduled:
            self._more_scheduled = True
            self._loop.call_soon(self._service_more)

    def _service_more(self) -> None:
        self._more_scheduled = False
        self._service()

    def _account(self, frame: bytes) -> None:
        """libzmq passes up a prefix when it enters the trie (first subscriber) and when it
        leaves it (last subscriber gone), plus any frame that is not a subscription."""
        if frame[:1] in (b"\x00", b"\x01") and is_known_prefix(frame[1:]):
            self.subscriptions = max(0, self.subscriptions + (1 if frame[:1] == b"\x01" else -1))
            return
        if frame[:1] == b"\x00" or self._rebinding:
            return  # a foreign prefix left the trie, or a reset is already under way
        self.foreign += 1
        if self.foreign > SUBSCRIPTION_BUDGET:
            self._drop_subscribers()

    def _drop_subscribers(self) -> None:
        """Unbinding closes every connection accepted on the endpoint, and with them their
        subscriptions; bind again once the listener has let go of the address."""
        self.resets += 1
        log.warning("publisher: %d subscriptions to no topic or non-subscription frames: dropping every "
                    "subscriber connection (reset %d); they reconnect", self.foreign, self.resets)
        self._rebinding = True
        try:
            self._sock.unbind(self._bound)
        except zmq.ZMQError as exc:
            log.error("publisher: unbind %s failed: %s", self._bound, exc)
        self._rebind()

    def _rebind(self) -> None:
        if self._closed or not self._rebinding:
            return
        try:
            self._sock.bind(self._bound)
        except zmq.ZMQError as exc:  # the old listener closes in libzmq's I/O thread: soon
            log.debug("publisher: rebind %s: %s", self._bound, exc)
            if self._loop is not None:
                self._loop.call_later(REBIND_RETRY_S, self._rebind)
            return
        self._rebinding = False
        self.foreign = 0
        log.info("publisher: listening again on %s", self._bound)

    def send(self, topic: str, t_s: float, payload: dict[str, Any]) -> None:
        self.seq += 1
        try:
            self._sock.send_multipart(encode(topic, self.seq, t_s, payload), flags=zmq.NOBLOCK)
        except zmq.Again:
            self.dropped += 1
        if self._rebinding and self._loop is None:
            self._rebind()
        self._service()

    def close(self) -> None:
        self._closed = True
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
