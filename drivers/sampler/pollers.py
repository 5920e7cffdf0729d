"""Pollers: built inside the sampler process, read once per slot.

A poller has ``channels`` (names), ``open()``, ``read() -> tuple of floats`` (SI units,
one per channel) and ``close()``. ``read`` may raise: the slot then counts as failed.
"""

from __future__ import annotations

import math
import time


class SyntheticPoller:
    """A deterministic signal for tests and benchmarks: p_act = amplitude*sin(2 pi f t),
    with an optional busy-wait per read (to stand in for I/O time) and scripted failures
    (read number -> raise)."""

    def __init__(self, channels: list[str] | None = None, frequency_hz: float = 1.0, amplitude: float = 1000.0,
                 read_time_us: float = 0.0, fail_reads: list[int] | None = None):
        self.channels = tuple(channels or ["p_act"])
        self.frequency_hz = frequency_hz
        self.amplitude = amplitude
        self.read_ns = int(read_time_us * 1000)
        self.fail = set(fail_reads or [])
        self.n = 0
        self._t0 = 0

    def open(self) -> None:
        self._t0 = time.monotonic_ns()

    def read(self) -> tuple[float, ...]:
        self.n += 1
        if self.n in self.fail:
            raise OSError(f"scripted failure at read {self.n}")
        if self.read_ns:
            end = time.monotonic_ns() + self.read_ns
            while time.monotonic_ns() < end:
                pass
        t = (time.monotonic_ns() - self._t0) / 1e9
        v = self.amplitude * math.sin(2 * math.pi * self.frequency_hz * t)
        return tuple(v for _ in self.channels)

    def close(self) -> None:
        return None
