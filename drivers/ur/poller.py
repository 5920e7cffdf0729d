"""Analog inputs of a UR control box through RTDE, read in the sampler process.

RTDE sends the box's state at a fixed rate (500 Hz e-Series); ur_rtde keeps the newest
packet and each read takes that. The sampler polls at the same rate on its own clock,
so a reading is the value of the newest packet, up to one RTDE period old. A slot that
finds no newer packet than the last one (the box's packet was late, or the two clocks
drifted) is a missed slot, never the old value stamped again; a stream that stays still
for ``stale_s`` means the robot stopped sending: a failed read, then a lost link.

Every field is the box's word, and a box can be wrong or hostile. What it cannot have
said is one DeviceProtocolError naming the field (the sampler ends, the daemon faults
``driver`` and connects again), as the serial driver does with its frames:

- ``timestamp``: not a finite number, or earlier than the one before (the controller's
  time since start never runs back within a connection), or ahead of the host clock
  since the connection's first packet by more than MAX_CLOCK_ERROR and LEAD_MARGIN_S (a
  jump forward, or a stream that claims more packets than its rate: a timestamp that
  runs ten times fast). A packet cannot be stamped after it arrives, so however late
  the host reads, timestamps never lead the host clock; only a first packet read late
  makes later ones look early, by at most LEAD_MARGIN_S;
- ``standard_analog_input0`` / ``1``: not a finite number, or outside what the input can
  measure in its domain (INPUT_RANGE).
"""

from __future__ import annotations

import math
import time

from fluidsense.common.errors import DeviceProtocolError

from ..child import keep_until_exit
from ..clockcheck import MAX_CLOCK_ERROR, lead_s
from ..sampler.poller import NoNewSample, Poller

_INPUTS = ("getStandardAnalogInput0", "getStandardAnalogInput1")
#: how old the session's first packet may be when the host reads it: ur_rtde's receive thread,
#: starved at the start on a loaded machine, parses a backlog of packets up to about a second
#: old. Wide, because the timestamp never sets sample time here (the sampler's slots do): the
#: bound has only to catch a clock that is not the box's
LEAD_MARGIN_S = 1.0
#: what a standard analog input reads, in RTDE's units (V, mA): UR's electrical ranges
#: (e-Series user manual, "Analog I/O": 0-10 V, 4-20 mA; 0 mA is an open current loop, a
#: sensor fault the controller judges, not a lie), widened by 10 % of the span for the
#: ADC's offset and gain error
INPUT_RANGE = {"voltage": (-1.0, 11.0), "current": (-2.0, 22.0)}


class TimestampGuard:
    """The checks of one connection's RTDE timestamps (see the module docstring)."""

    def __init__(self) -> None:
        self._last = -math.inf
        self._first: tuple[float, float] | None = None  # (timestamp, host s) of the first packet

    def check(self, stamp: float, host_s: float) -> None:
        if not math.isfinite(stamp):
            raise DeviceProtocolError(f"timestamp: {stamp!r} is not a time", "timestamp")
        if stamp < self._last:
            raise DeviceProtocolError(f"timestamp: {stamp:.6f} s after {self._last:.6f} s: the box's clock ran "
                                      f"back {self._last - stamp:.6g} s", "timestamp")
        if self._first is None:
            self._first = (stamp, host_s)
        if lead_s(stamp - self._first[0], host_s - self._first[1], LEAD_MARGIN_S) > 0:
            box_s, since = stamp - self._first[0], host_s - self._first[1]
            raise DeviceProtocolError(f"timestamp: {box_s:.6g} s of the box's time in {since:.3f} s of the host's "
                                      f"(the box's stream runs ~{box_s / max(since, 1e-3):.3g} times its rate, "
                                      f"or its clock jumped; allowed {MAX_CLOCK_ERROR:.0%} off)", "timestamp")
        self._last = stamp


class RtdeAnalogPoller(Poller):
    def __init__(self, host: str, frequency: float, inputs: list[list], upper_range_registers: bool = False,
                 stale_s: float = 0.5) -> None:
        """``inputs``: per channel ``[analog input, k, c, domain]``: Pa = k * reading + c,
        the reading in V or mA as RTDE reports it, ``domain`` "voltage" or "current". A
        timestamp that has not moved for ``stale_s`` means the robot stopped sending: reads
        fail."""
        self.host, self.frequency = host, float(frequency)
        self.inputs = [(int(ch), float(k), float(c)) for ch, k, c, _ in inputs]
        self.ranges = [(int(ch), INPUT_RANGE[domain], "V" if domain == "voltage" else "mA")
                       for ch, _, _, domain in inputs]
        self.upper = bool(upper_range_registers)
        self.stale_ns = int(stale_s * 1e9)
        self.receive = None
        self._stamp = -1.0
        self._stamp_at = 0
        self._guard = TimestampGuard()

    def open(self) -> None:
        import rtde_receive  # noqa: PLC0415 - only in the sampler process

        self.receive = rtde_receive.RTDEReceiveInterface(
            self.host, self.frequency, ["timestamp", "standard_analog_input0", "standard_analog_input1"], False,
            self.upper)
        self._getters = [getattr(self.receive, _INPUTS[ch]) for ch, _, _ in self.inputs]
        self._stamp_at = time.monotonic_ns()

    def read(self) -> tuple[float, ...]:
        r = self.receive
        stamp = r.getTimestamp()
        now = time.monotonic_ns()
        if stamp == self._stamp:
            if now - self._stamp_at > self.stale_ns:
                raise ConnectionError(f"RTDE data from {self.host} stale for {(now - self._stamp_at) / 1e9:.3f} s")
            raise NoNewSample
        self._guard.check(stamp, now / 1e9)
        self._stamp, self._stamp_at = stamp, now
        readings = [get() for get in self._getters]
        for reading, (ch, (lo, hi), unit) in zip(readings, self.ranges):
            if not lo <= reading <= hi:  # NaN included
                raise DeviceProtocolError(f"standard_analog_input{ch}: {reading!r} {unit} is outside what the input "
                                          f"can measure ({lo:g} to {hi:g} {unit})", f"standard_analog_input{ch}")
        return tuple(k * reading + c for reading, (_, k, c) in zip(readings, self.inputs))

    def close(self) -> None:
        if self.receive is not None:
            self.receive.disconnect()
            keep_until_exit(self.receive)  # its destructor would wait 0.5 s (drivers/child.py)
