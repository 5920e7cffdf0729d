"""Fault kinds: one vocabulary for the supervisor, the safety latch, the drivers' fault
injection, the benches and the published ``fault`` events (docs/safety.md)."""

from __future__ import annotations

import enum
from dataclasses import dataclass


class FaultKind(enum.StrEnum):
    # what the supervisor finds in a block
    OVER_PRESSURE = "over_pressure"
    UNDER_PRESSURE = "under_pressure"
    SENSOR_NAN = "sensor_nan"
    SENSOR_RANGE = "sensor_range"
    SENSOR_STUCK = "sensor_stuck"
    LEAK = "leak"
    PROTECTIVE_STOP = "protective_stop"
    # blocks that do not arrive, or arrive late
    NO_DATA = "no_data"
    LINK_LOST = "link_lost"
    OVERRUN = "overrun"
    # failures of the service's own parts
    DRIVER = "driver"  # a device raised something other than a lost link or a timeout
    COMMAND = "command"  # a valve, regulator or flow command the device did not carry out
    INTERNAL = "internal"  # an unexpected exception inside the service (a bug): vented all the same


@dataclass(frozen=True)
class Fault:
    kind: FaultKind
    channel: str | None
    t: float  # sample time of the first evidence
    detail: str
