"""The blocking client: ``Gripper(cmd_endpoint, pub_endpoint)``."""

from __future__ import annotations

import json
import time
from collections import deque
from collections.abc import Iterator
from typing import Any

import zmq

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


class Gripper:
    def __init__(self, cmd: str = "tcp://127.0.0.1:5561", pub: str = "tcp://127.0.0.1:5560", *,
                 timeout_s: float = 10.0, event_timeout_s: float = 120.0, curve: tuple[str, str] | None = None,
                 topics: tuple[str, ...] = (*GRIPPER_TOPICS, "fault")):
        """``timeout_s``: for a reply; ``event_timeout_s``: for an event (a grip's grasp
        comes after charging and the measurement windows: tens of seconds on some
        profiles); ``curve``: (client secret key file, server public key file)."""
        self.cmd_endpoint, self.pub_endpoint = cmd, pub
        self.timeout_s, self.event_timeout_s = timeout_s, event_timeout_s
        self._keys = S.curve_keys(curve)
        self._ctx = zmq.Context()
        self._req: zmq.Socket | None = None
        self._sub = S.setup_sub(self._ctx.socket(zmq.SUB), pub, topics)
        self._pending: deque[Event] = deque(maxlen=10_000)
        self._attached = False

    # ------------------------------------------------------------------ requests
    def request(self, body: dict[str, Any], timeout_s: float | None = None) -> dict[str, Any]:
        """One request; its reply (``Refused`` for an error reply, ``NoReply`` after the
        timeout, and the next request goes over a new socket)."""
        self.attach()
        if self._req is None:
            self._req = S.setup_req(self._ctx.socket(zmq.REQ), self.cmd_endpoint, self._keys)
        self._req.send(json.dumps(body).encode())
        if not self._req.poll(int(1000 * (self.timeout_s if timeout_s is None else timeout_s))):
            self._req.close()
            self._req = None
            raise NoReply(f"no reply to {body.get('cmd')!r} from {self.cmd_endpoint}")
        reply = json.loads(self._req.recv())
        if not reply.get("ok"):
            raise Refused(body, reply)
        return reply

    def status(self) -> dict[str, Any]:
        return self.request({"cmd": "status"})

    def grip(self, p0_kpa: float | None = None, timeout_s: float | None = None, label: str | None = None,
             wait: bool = True) -> Grasp | int:
        """Close on what is there and stay holding; the grasp (or the cycle id with
        ``wait=False``). ``GripEnded`` if the cycle ends first (aborted, a fault)."""
        reply = self.request(S.request_body("grip", p0_kpa=p0_kpa, timeout_s=timeout_s, label=label))
        if not wait:
            return reply["cycle_id"]
        return Grasp.of(self.wait_for("grasp", reply["cycle_id"], self._event_timeout(timeout_s), fail_on_end=True))

    def measure(self, p0_kpa: float | None = None, label: str | None = None, store_reference: bool = False,
                wait: bool = True) -> Grasp | int:
        """One sensing cycle (the gripper opens again by itself); its grasp."""
        reply = self.request(S.request_body("measure", p0_kpa=p0_kpa, label=label,
                                            store_reference=store_reference or None))
        if not wait:
            return reply["cycle_id"]
        grasp = Grasp.of(self.wait_for("grasp", reply["cycle_id"], self.event_timeout_s, fail_on_end=True))
        self.wait_for("released", reply["cycle_id"], self.event_timeout_s)
        return grasp

    def release(self, wait: bool = True) -> Released | int:
        """Open (vent); once open, the ``released`` event."""
        reply = self.request({"cmd": "release"})
        if not wait:
            return reply["cycle_id"]
        return Released.of(self.wait_for("released", reply["cycle_id"], self.event_timeout_s))

    def abort(self, reason: str = "client") -> bool:
        return self.request({"cmd": "abort", "reason": reason})["aborted"]

    def reset(self) -> str:
        return self.request({"cmd": "reset"})["state"]

    def scene(self, scene: dict[str, Any]) -> dict[str, Any]:
        """Simulated cells only: place an object (``{"kind": "cylinder", "diameter_mm": 60}``)."""
        return self.request({"cmd": "scene", "scene": scene})["scene"]

    # ------------------------------------------------------------------ events
    def attach(self, timeout_s: float | None = None) -> None:
        """Wait until the daemon has attached the subscription (its welcome): no event
        published after that is lost to ZeroMQ's slow-joiner gap."""
        deadline = time.monotonic() + (self.timeout_s if timeout_s is None else timeout_s)
        while not self._attached:
            if not self._sub.poll(max(0, int(1000 * (deadline - time.monotonic())))):
                raise NoReply(f"no welcome from {self.pub_endpoint}: is the daemon running?")
            self._take(self._sub.recv_multipart())

    def _take(self, frames: list[bytes]) -> Event | None:
        if frames == [S.WELCOME]:
            self._attached = True
            return None
        return S.decode(frames)

    def next_event(self, timeout_s: float | None = None) -> Event | None:
        """The next event (None after ``timeout_s``; None: wait for ever)."""
        if self._pending:
            return self._pending.popleft()
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            wait = -1 if deadline is None else max(0, int(1000 * (deadline - time.monotonic())))
            if not self._sub.poll(wait):
                return None
            ev = self._take(self._sub.recv_multipart())
            if ev is not None:
                return ev

    def events(self, timeout_s: float | None = None) -> Iterator[Any]:
        """Typed events (Grasp, Contact, Slip, Released; Event for other topics) until
        ``timeout_s`` passes without one."""
        while (ev := self.next_event(timeout_s)) is not None:
            yield typed(ev)

    def wait_for(self, topic: str, cycle_id: int | None, timeout_s: float, fail_on_end: bool = False) -> Event:
        """The next ``topic`` event of the cycle; others are kept for ``events()``."""
        deadline = time.monotonic() + timeout_s
        skipped: list[Event] = []
        try:
            while True:
                ev = self.next_event(max(0.0, deadline - time.monotonic()))
                if ev is None:
                    raise NoReply(f"no {topic} of cycle {cycle_id} within {timeout_s:g} s")
                if S.matches(ev, topic, cycle_id):
                    return ev
                skipped.append(ev)
                if fail_on_end and S.matches(ev, "released", cycle_id):
                    raise GripEnded(Released.of(ev))
        finally:
            self._pending.extendleft(reversed(skipped))

    def _event_timeout(self, timeout_s: float | None) -> float:
        return self.event_timeout_s if timeout_s is None else timeout_s + self.timeout_s

    def close(self) -> None:
        if self._req is not None:
            self._req.close()
        self._sub.close()
        self._ctx.term()

    def __enter__(self) -> Gripper:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
