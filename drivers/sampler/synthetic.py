"""A synthetic poller for tests and benchmarks: a deterministic signal, an optional
busy wait per read standing in for I/O time, and scripted failures.

Read n (counting every call to ``read()``, failed ones included) returns, for channel
c of C, ``offset_pa + amplitude_pa * sin(2 pi (n / cycle_reads + c / C))``;
:meth:`SyntheticPoller.expected` gives the same numbers to a test.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable

from .poller import Poller


class SyntheticPoller(Poller):
    def __init__(self, channels: int = 1, offset_pa: float = 0.0, amplitude_pa: float = 1000.0,
                 cycle_reads: int = 1000, busy_us: float = 0.0, fail_reads: Iterable[int] = (),
                 fail_from: int | None = None, open_error: str | None = None) -> None:
        """``busy_us``: spin this long in every read (a Modbus round trip on a LAN is
        100-300 us). ``fail_reads``: read numbers that raise ConnectionError;
        ``fail_from``: every read from this number on raises (a cable pulled).
        ``open_error``: ``open()`` raises ConnectionRefusedError with this text."""
        if channels < 1 or cycle_reads < 1 or busy_us < 0:
            raise ValueError("channels >= 1, cycle_reads >= 1 and busy_us >= 0 are required")
        self.channels = int(channels)
        self.offset_pa = float(offset_pa)
        self.amplitude_pa = float(amplitude_pa)
        self.cycle_reads = int(cycle_reads)
        self.busy_ns = int(busy_us * 1000)
        self.fail_reads = frozenset(int(n) for n in fail_reads)
        self.fail_from = fail_from
        self.open_error = open_error
        self.reads = 0
        self.opened = False
        self.closed = False

    def open(self) -> None:
        if self.open_error is not None:
            raise ConnectionRefusedError(self.open_error)
        self.opened = True

    def read(self) -> tuple[float, ...]:
        n = self.reads
        self.reads += 1
        if self.busy_ns:
            end = time.perf_counter_ns() + self.busy_ns
            while time.perf_counter_ns() < end:
                pass
        if n in self.fail_reads or (self.fail_from is not None and n >= self.fail_from):
            raise ConnectionError(f"synthetic failure at read {n}")
        return self.expected(n)

    def expected(self, n: int) -> tuple[float, ...]:
        """What read ``n`` returns (when it does not fail)."""
        phase = n / self.cycle_reads
        return tuple(self.offset_pa + self.amplitude_pa * math.sin(2 * math.pi * (phase + c / self.channels))
                     for c in range(self.channels))

    def close(self) -> None:
        self.closed = True
