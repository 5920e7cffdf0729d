"""What the client library returns: typed views of the daemon's replies and events
(docs/zmq-schema.md), and its errors."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from fluidsense.common.errors import CommandError, DeviceTimeoutError, FluidsenseError


class Refused(CommandError):
    """The daemon answered a request with an error (``reply`` holds it all)."""

    def __init__(self, request: dict[str, Any], reply: dict[str, Any]):
        super().__init__(f"{request.get('cmd', '?')} refused: {reply.get('error')}")
        self.request, self.reply = request, reply


class NoReply(DeviceTimeoutError):
    """No reply or no event in time. The request socket is made again after one."""


class NoWelcome(NoReply):
    """The subscription was not attached in time: no daemon, or no publisher at the
    endpoint (the sockets say which: client/_sockets.py)."""


class GripEnded(FluidsenseError, RuntimeError):
    """The cycle ended (aborted, faulted, timed out) before what was asked: its grasp, or
    a ``release`` of a grip that had already opened by itself. ``released`` says why."""

    def __init__(self, released: Released, before: str = "its grasp"):
        super().__init__(f"cycle {released.cycle_id} ended before {before}: {released.reason}")
        self.released = released


class DaemonRestarted(FluidsenseError, ConnectionError):
    """A call waited for events of the daemon instance that answered its request, and
    another instance (a restart on the same endpoints) welcomed the subscription: those
    events will never come, and cycle ids start again at 1, so a later event with the same
    id is another client's. ``waited``: the instance id waited on, ``now``: the new one."""

    def __init__(self, what: str, waited: str, now: str):
        super().__init__(f"the daemon was restarted while waiting for {what} (instance {waited}, now {now}): "
                         "its events will not come; request again")
        self.waited, self.now = waited, now


@dataclass(frozen=True)
class Estimate:
    quantity: str  # "diameter", "height", ...
    value_mm: float | None
    lo_mm: float | None
    hi_mm: float | None
    coverage: float
    status: str  # "ok", "no_object", "out_of_range"
    feature: str | None = None

    @classmethod
    def of(cls, d: dict[str, Any]) -> Estimate:
        return cls(d["quantity"], d["value_mm"], d["lo_mm"], d["hi_mm"], d["coverage"], d["status"], d.get("feature"))


@dataclass(frozen=True)
class Event:
    """Any published message: ``topic``, its sequence numbers and times, ``instance`` (the
    daemon's id, "" from a daemon that sends none), and ``data``."""

    topic: str
    seq: int
    topic_seq: int
    t_s: float
    utc_s: float
    data: dict[str, Any] = field(repr=False)
    instance: str = ""

    @classmethod
    def of(cls, msg: dict[str, Any]) -> Event:
        return cls(msg["topic"], msg["seq"], msg.get("topic_seq", msg["seq"]), msg["t_s"], msg.get("utc_s", 0.0), msg,
                   str(msg.get("instance") or ""))


@dataclass(frozen=True)
class Grasp:
    cycle_id: int
    object: bool | None  # None: cannot be told (no free-air reference)
    contact: bool | None
    t_c_s: float | None
    estimates: tuple[Estimate, ...]
    in_range: bool | None
    features: dict[str, Any]
    note: str | None
    event: Event = field(repr=False)

    @property
    def size(self) -> Estimate | None:
        """The first estimate (a gripper's calibration is usually one: its diameter)."""
        return self.estimates[0] if self.estimates else None

    @classmethod
    def of(cls, ev: Event) -> Grasp:
        d = ev.data
        return cls(d["cycle_id"], d["object"], d["contact"], d["t_c_s"], tuple(Estimate.of(e) for e in d["estimates"]),
                   d["in_range"], d["features"], d["note"], ev)


@dataclass(frozen=True)
class Contact:
    cycle_id: int
    at_s: float
    t_c_s: float
    event: Event = field(repr=False)

    @classmethod
    def of(cls, ev: Event) -> Contact:
        return cls(ev.data["cycle_id"], ev.data["at_s"], ev.data["t_c_s"], ev)


@dataclass(frozen=True)
class Slip:
    cycle_id: int
    at_s: float
    held_s: float
    drop_kpa: float
    object: bool | None
    estimates: tuple[Estimate, ...]
    event: Event = field(repr=False)

    @classmethod
    def of(cls, ev: Event) -> Slip:
        d = ev.data
        return cls(d["cycle_id"], d["at_s"], d["held_s"], d["drop_kpa"], d["object"],
                   tuple(Estimate.of(e) for e in d["estimates"]), ev)


@dataclass(frozen=True)
class Released:
    cycle_id: int
    reason: str
    held_s: float | None
    ok: bool
    event: Event = field(repr=False)

    @classmethod
    def of(cls, ev: Event) -> Released:
        d = ev.data
        return cls(d["cycle_id"], d["reason"], d["held_s"], d["ok"], ev)


TYPED = {"grasp": Grasp, "contact": Contact, "slip": Slip, "released": Released}


def typed(ev: Event) -> Any:
    """The typed view of a gripper event, the Event itself for other topics."""
    kind = TYPED.get(ev.topic)
    return ev if kind is None else kind.of(ev)
