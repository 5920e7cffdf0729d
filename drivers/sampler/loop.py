"""The slot loop: deadlines on a fixed grid, exact accounting, no catching up.

Written against a ``Clock`` so that tests can inject lateness and missed slots and check
the accounting exactly; the process runs it with the real clock.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np


class Clock(Protocol):
    def now_ns(self) -> int: ...

    def sleep_until(self, deadline_ns: int) -> None: ...


class RealClock:
    """``time.monotonic_ns``; sleep until ``spin_ns`` before the deadline, then spin: the
    kernel's sleep wakes late by tens of microseconds, the spin does not."""

    def __init__(self, spin_ns: int = 200_000):
        self.spin_ns = spin_ns

    def now_ns(self) -> int:
        return time.monotonic_ns()

    def sleep_until(self, deadline_ns: int) -> None:
        gap = deadline_ns - self.spin_ns - time.monotonic_ns()
        if gap > 0:
            time.sleep(gap / 1e9)
        while time.monotonic_ns() < deadline_ns:
            pass


@dataclass
class Block:
    """Samples and the slot accounting since the previous block."""

    t_ns: list[int] = field(default_factory=list)
    values: list[tuple[float, ...]] = field(default_factory=list)
    lateness_ns: list[int] = field(default_factory=list)
    on_time: int = 0
    late: int = 0
    missed: int = 0
    failed: int = 0
    link_lost: str | None = None

    @property
    def slots(self) -> int:
        return self.on_time + self.late + self.missed + self.failed

    def arrays(self, n_channels: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = np.asarray(self.t_ns, dtype=np.int64)
        v = np.asarray(self.values, dtype=float).reshape(len(self.values), n_channels)
        return t, v, np.asarray(self.lateness_ns, dtype=np.int64)


class SlotLoop:
    def __init__(self, clock: Clock, period_ns: int, read: Callable[[], tuple[float, ...]],
                 emit: Callable[[Block], None], block_size: int, late_threshold_ns: int,
                 max_consecutive_failures: int = 10):
        self.clock = clock
        self.period = int(period_ns)
        self.read = read
        self.emit = emit
        self.block_size = block_size
        self.late_threshold = int(late_threshold_ns)
        self.max_failures = max_consecutive_failures
        self.stop = False
        self.totals = Block()

    def run(self, max_slots: int | None = None, t0_ns: int | None = None) -> None:
        """Run until ``stop`` is set (or ``max_slots`` slots have been accounted for)."""
        t0 = (self.clock.now_ns() + self.period) if t0_ns is None else t0_ns
        k = 0
        block = Block()
        failures = 0
        while not self.stop and (max_slots is None or k < max_slots):
            deadline = t0 + k * self.period
            self.clock.sleep_until(deadline)
            now = self.clock.now_ns()
            behind = (now - deadline) // self.period
            if behind > 0:  # woke after later slots' deadlines: those are gone
                skipped = behind if max_slots is None else min(behind, max_slots - k)
                block.missed += skipped
                k += skipped
                if max_slots is not None and k >= max_slots:
                    break
                deadline = t0 + k * self.period
            lateness = now - deadline
            try:
                values = self.read()
            except Exception as exc:  # noqa: BLE001 - a failed slot is data, not a crash
                block.failed += 1
                failures += 1
                k += 1
                if failures >= self.max_failures:
                    block.link_lost = f"{failures} reads failed in a row; last: {type(exc).__name__}: {exc}"
                    self._emit(block)
                    return
                continue
            failures = 0
            block.t_ns.append(now)
            block.values.append(tuple(values))
            block.lateness_ns.append(lateness)
            if lateness > self.late_threshold:
                block.late += 1
            else:
                block.on_time += 1
            k += 1
            if len(block.t_ns) >= self.block_size:
                self._emit(block)
                block = Block()
        if block.slots:
            self._emit(block)

    def _emit(self, block: Block) -> None:
        tot = self.totals
        tot.on_time += block.on_time
        tot.late += block.late
        tot.missed += block.missed
        tot.failed += block.failed
        self.emit(block)
