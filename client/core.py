"""The client's one core, under the blocking and the asyncio faces (sync.py, aio.py).

Every call of the client is written here once, as a generator that does no I/O: it
yields a step (``Exchange``: a request and its reply; ``Listen``: the next message of
the subscription), is sent back what came of it, and returns the call's result. A face
runs the steps its own way, blocking or awaited, and decides nothing else. So what a
request does after a timeout, how an attached subscription is known (the daemon's
welcome), and which event a wait is for are decided in one place: ``Session._take`` sees
every message that arrives, ``matches`` decides every wait. A wait is tied to the daemon
instance that answered its request (its id is in the reply, the welcome and every event):
cycle ids start again at 1 after a restart, so an id alone would match another client's
cycle on the new daemon. A welcome from another instance ends the wait (``DaemonRestarted``).
"""

from __future__ import annotations

import inspect
import json
import time
from collections import deque
from collections.abc import Generator
from dataclasses import dataclass
from typing import Any, TypeVar

from fluidsense.common.names import welcome_instance

from .types import DaemonRestarted, Event, Grasp, GripEnded, NoReply, NoWelcome, Refused, Released

T = TypeVar("T")


@dataclass(frozen=True)
class Exchange:
    """Send ``body`` on the request socket and wait up to ``timeout_s`` for the reply: its
    bytes, or None. After None the face closes that socket (a REQ socket that missed its
    reply is stuck) and the next exchange goes over a new one."""

    body: bytes
    timeout_s: float


@dataclass(frozen=True)
class Listen:
    """The next message of the subscription within ``timeout_s`` (None: no limit): its
    frames, or None."""

    timeout_s: float | None


Call = Generator[Exchange | Listen, Any, T]


def request_body(cmd: str, **fields: Any) -> dict[str, Any]:
    return {"cmd": cmd, **{k: v for k, v in fields.items() if v is not None}}


def decode(frames: list[bytes]) -> Event | None:
    """An event, or None for anything that is not a published message."""
    if len(frames) != 2:
        return None
    try:
        return Event.of(json.loads(frames[1]))
    except (ValueError, KeyError, TypeError):
        return None


def matches(ev: Event, topic: str, cycle_id: int | None, instance: str = "") -> bool:
    """``instance`` "": any (a daemon that sends no id)."""
    return (ev.topic == topic and (cycle_id is None or ev.data.get("cycle_id") == cycle_id)
            and (not instance or not ev.instance or ev.instance == instance))


def _left(deadline: float | None) -> float | None:
    return None if deadline is None else max(0.0, deadline - time.monotonic())


class Session:
    """What one client knows between calls (the events read but not yet asked for, whether
    its subscription is attached) and its calls. ``pub`` None: requests only."""

    def __init__(self, cmd: str, pub: str | None, timeout_s: float, event_timeout_s: float):
        self.cmd_endpoint, self.pub_endpoint = cmd, pub
        self.timeout_s, self.event_timeout_s = timeout_s, event_timeout_s
        self.pending: deque[Event] = deque(maxlen=10_000)
        self.attached = pub is None  # nothing to attach to
        self.instance = ""  # the daemon instance of the last welcome ("" before one, or none sent)
        self._restarted: str | None = None  # a welcome from another instance came: its id
        self.held: tuple[int, str] | None = None  # the grip this client closed and has not released: cycle, instance

    # ------------------------------------------------------------------ requests
    def request(self, body: dict[str, Any], timeout_s: float | None = None) -> Call[dict[str, Any]]:
        """One request; its reply (``Refused`` for an error reply, ``NoReply`` after the
        timeout, and the next request goes over a new socket)."""
        yield from self.attach()
        raw = yield Exchange(json.dumps(body).encode(), self.timeout_s if timeout_s is None else timeout_s)
        if raw is None:
            raise NoReply(f"no reply to {body.get('cmd')!r} from {self.cmd_endpoint}")
        reply = json.loads(raw)
        if not reply.get("ok"):
            raise Refused(body, reply)
        return reply

    def status(self) -> Call[dict[str, Any]]:
        return (yield from self.request({"cmd": "status"}))

    def grip(self, p0_kpa: float | None = None, timeout_s: float | None = None, label: str | None = None,
             wait: bool = True) -> Call[Grasp | int]:
        """Close on what is there and stay holding; the grasp (or the cycle id with
        ``wait=False``). ``GripEnded`` if the cycle ends first (aborted, a fault)."""
        reply = yield from self.request(request_body("grip", p0_kpa=p0_kpa, timeout_s=timeout_s, label=label))
        if not wait:
            return reply["cycle_id"]
        limit = self.event_timeout_s if timeout_s is None else timeout_s + self.timeout_s
        grasp = Grasp.of((yield from self.wait_for("grasp", reply["cycle_id"], limit, fail_on_end=True,
                                                   instance=self._of(reply))))
        self.held = (reply["cycle_id"], self._of(reply))
        return grasp

    def measure(self, p0_kpa: float | None = None, label: str | None = None, store_reference: bool = False,
                wait: bool = True) -> Call[Grasp | int]:
        """One sensing cycle (the gripper opens again by itself); its grasp."""
        reply = yield from self.request(request_body("measure", p0_kpa=p0_kpa, label=label,
                                                     store_reference=store_reference or None))
        if not wait:
            return reply["cycle_id"]
        grasp = Grasp.of((yield from self.wait_for("grasp", reply["cycle_id"], self.event_timeout_s,
                                                   fail_on_end=True, instance=self._of(reply))))
        yield from self.wait_for("released", reply["cycle_id"], self.event_timeout_s, instance=self._of(reply))
        return grasp

    def release(self, wait: bool = True) -> Call[Released | int]:
        """Open (vent); once open, the ``released`` event. ``GripEnded`` when the grip this
        client holds had already opened by itself (a fault, an abort, its timeout): the
        daemon refuses the release, and the ``released`` event says why it opened."""
        held, self.held = self.held, None
        try:
            reply = yield from self.request({"cmd": "release"})
        except Refused as refused:
            if held is None or "nothing to release" not in str(refused.reply.get("error")):
                raise
            # the daemon published the event before it answered, on another socket: it is
            # read already or on its way
            try:
                ev = yield from self.wait_for("released", held[0], self.timeout_s, instance=held[1])
            except (NoReply, DaemonRestarted):
                raise refused from None
            raise GripEnded(Released.of(ev), "its release") from refused
        if not wait:
            return reply["cycle_id"]
        return Released.of((yield from self.wait_for("released", reply["cycle_id"], self.event_timeout_s,
                                                     instance=self._of(reply))))

    def abort(self, reason: str = "client") -> Call[bool]:
        return (yield from self.request({"cmd": "abort", "reason": reason}))["aborted"]

    def reset(self) -> Call[str]:
        return (yield from self.request({"cmd": "reset"}))["state"]

    def scene(self, scene: dict[str, Any]) -> Call[dict[str, Any]]:
        """Simulated cells only: place an object (``{"kind": "cylinder", "diameter_mm": 60}``)."""
        return (yield from self.request({"cmd": "scene", "scene": scene}))["scene"]

    # ------------------------------------------------------------------ events
    def attach(self, timeout_s: float | None = None) -> Call[None]:
        """Wait until the daemon has attached the subscription (its welcome): no event
        published after that is lost to ZeroMQ's slow-joiner gap."""
        deadline = time.monotonic() + (self.timeout_s if timeout_s is None else timeout_s)
        while not self.attached:
            frames = yield Listen(_left(deadline))
            if frames is None:
                raise NoWelcome(f"no welcome from {self.pub_endpoint}: is the daemon running?")
            self._take(frames)

    def next_event(self, timeout_s: float | None = None) -> Call[Event | None]:
        """The next event (None after ``timeout_s``; None: wait for ever)."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        return (yield from self._next(deadline))

    def _next(self, deadline: float | None, until_restart: bool = False) -> Call[Event | None]:
        """The next event before ``deadline``; with ``until_restart``, None as soon as
        another daemon instance welcomes the subscription too."""
        if self.pending:
            return self.pending.popleft()
        if self.pub_endpoint is None:
            raise ValueError("this client subscribes to nothing (made with pub=None)")
        while True:
            frames = yield Listen(_left(deadline))
            if frames is None:
                return None
            ev = self._take(frames)
            if ev is not None:
                return ev
            if until_restart and self._restarted is not None:
                return None

    def wait_for(self, topic: str, cycle_id: int | None, timeout_s: float, fail_on_end: bool = False,
                 instance: str | None = None) -> Call[Event]:
        """The next ``topic`` event of the cycle from daemon ``instance`` (None: the one
        that welcomed this client last; "": any); others are kept for ``events()``.
        ``DaemonRestarted`` once another instance welcomes the subscription."""
        instance = self.instance if instance is None else instance
        what = f"{topic} of cycle {cycle_id}"
        deadline = time.monotonic() + timeout_s
        skipped: list[Event] = []
        self._restarted = None
        try:
            while True:
                ev = yield from self._next(deadline, until_restart=bool(instance))
                if ev is not None and matches(ev, topic, cycle_id, instance):
                    return ev
                if self._restarted is not None and instance and self._restarted != instance:
                    raise DaemonRestarted(what, instance, self._restarted)
                if ev is None:
                    raise NoReply(f"no {what} within {timeout_s:g} s")
                skipped.append(ev)
                if fail_on_end and matches(ev, "released", cycle_id, instance):
                    raise GripEnded(Released.of(ev))
        finally:
            self.pending.extendleft(reversed(skipped))

    def _of(self, reply: dict[str, Any]) -> str:
        """The instance that answered a request: its reply says (a daemon before schema
        version 2 does not: then the last welcome's)."""
        return str(reply.get("instance") or self.instance)

    def _take(self, frames: list[bytes]) -> Event | None:
        """Every message of the subscription comes through here: the welcome attaches it
        (and says which daemon instance it is), an event is decoded, anything else is
        passed over."""
        welcome = welcome_instance(frames)
        if welcome is None:
            return decode(frames)
        self.attached = True
        if welcome and welcome != self.instance:
            self._restarted = welcome if self.instance else None
            self.instance = welcome
        return None


#: the calls a face offers: every public generator method of the session
CALLS = tuple(name for name, fn in vars(Session).items() if not name.startswith("_") and inspect.isgeneratorfunction(fn))


def face_signature(call: Any) -> inspect.Signature:
    """A call's signature as a face offers it: what the call returns, not its generator."""
    sig = inspect.signature(call)
    ret = sig.return_annotation
    if isinstance(ret, str) and ret.startswith("Call[") and ret.endswith("]"):
        ret = ret[len("Call["):-1]
    return sig.replace(return_annotation=ret)
