"""Analog inputs of a UR control box through RTDE, read in the sampler process.

RTDE sends the box's state at a fixed rate (500 Hz e-Series); ur_rtde keeps the newest
packet and each read takes that. The sampler polls at the same rate on its own clock,
so a reading is the value of the newest packet, up to one RTDE period old. A slot that
finds no newer packet than the last one (the box's packet was late, or the two clocks
drifted) is a missed slot, never the old value stamped again; a stream that stays still
for ``stale_s`` means the robot stopped sending: a failed read, then a lost link.
"""

from __future__ import annotations

import time

from ..child import keep_until_exit
from ..sampler.poller import NoNewSample, Poller

_INPUTS = ("getStandardAnalogInput0", "getStandardAnalogInput1")


class RtdeAnalogPoller(Poller):
    def __init__(self, host: str, frequency: float, inputs: list[list[float]], upper_range_registers: bool = False,
                 stale_s: float = 0.5) -> None:
        """``inputs``: per channel ``[analog input, k, c]``: Pa = k * reading + c, the
        reading in V or mA as RTDE reports it. A timestamp that has not moved for
        ``stale_s`` means the robot stopped sending: reads fail."""
        self.host, self.frequency = host, float(frequency)
        self.inputs = [(int(ch), float(k), float(c)) for ch, k, c in inputs]
        self.upper = bool(upper_range_registers)
        self.stale_ns = int(stale_s * 1e9)
        self.receive = None
        self._stamp = -1.0
        self._stamp_at = 0

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
        self._stamp, self._stamp_at = stamp, now
        return tuple(k * get() + c for get, (_, k, c) in zip(self._getters, self.inputs))

    def close(self) -> None:
        if self.receive is not None:
            self.receive.disconnect()
            keep_until_exit(self.receive)  # its destructor would wait 0.5 s (drivers/child.py)
