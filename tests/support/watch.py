"""A daemon's published messages, read as they come, with its faults kept."""

from __future__ import annotations

import json
import time

import zmq
from support.harness import Daemon


class Watch:
    """Every message the daemon publishes, read as it comes: the faults are counted."""

    def __init__(self, d: Daemon):
        self.d = d
        self.faults: list[dict] = []

    def _take(self, topic: str, msg: dict) -> None:
        if topic == "fault":
            self.faults.append(msg)

    def until(self, want, timeout_s: float = 60.0, within_s: float | None = None) -> dict:
        """Read messages until ``want(topic, msg)``; that message. ``timeout_s`` bounds the
        wait for each message, ``within_s`` the whole wait (heartbeats keep coming: a wanted
        message that never comes would otherwise be waited for until the test's timeout)."""
        deadline = None if within_s is None else time.monotonic() + within_s
        while True:
            assert deadline is None or time.monotonic() < deadline, f"not within {within_s} s; faults {self.faults}"
            topic, msg = self.d.next_message(timeout_s=timeout_s)
            self._take(topic, msg)
            if want(topic, msg):
                return msg

    def drain(self) -> None:
        while self.d.sub.poll(0):
            frames = self.d.sub.recv_multipart(zmq.NOBLOCK)
            if len(frames) == 2:
                self._take(frames[0].decode(), json.loads(frames[1]))

    def samples_past(self, n: int) -> dict:
        """Status once the loop has taken ``n`` more samples (each request waits on the daemon)."""
        first = self.d.request({"cmd": "status"})["samples"]
        while (status := self.d.request({"cmd": "status"}))["samples"] < first + n:
            self.d.sub.poll(100)  # the next message, or 0.1 s: the proxy's thread needs this process too
            self.drain()
        self.drain()
        return status
