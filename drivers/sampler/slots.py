"""The slot loop: one read per slot on an absolute time grid, every slot accounted once.

Slot k has the deadline ``t0 + k * period`` (absolute: errors never accumulate). The
loop waits for the deadline (the clock sleeps to about 200 us before it, then spins),
stamps the time, reads the poller and files the slot in exactly one of four bins:

- on time: the read started at most ``late_threshold`` after the deadline;
- late: it started later than that, but before the next slot's deadline; the
  lateness is recorded with the sample;
- missed: the loop only got to it after the *next* slot's deadline had passed. A
  missed slot produces no sample. The loop re-aligns to the grid (it serves the
  newest slot whose deadline has passed) and never reads twice in a row to catch up;
- failed: the read raised. When reads have failed in a row for ``link_timeout_ns``
  (and at least ``max_consecutive_failures`` times) the loop reports link loss and ends.

A read that raises ``NoNewSample`` (nothing new at the source since the last read) is
a missed slot: no sample, and no step towards link loss. So is a read that took longer
than one period (a *slow* read, counted apart as well): the device answered with what it
had at some moment during the read, and which moment is not known; stamped with the
read's start, a sample on a steep rise was off by the whole read (an emulated box busy
for 19 ms after a valve opened answered a read begun at 22 ms with its 41 ms value, and
the rise alignment found 5 ms of shift that was not there).

Each sample carries the time its read started (never its deadline, never an
interpolation), so ``t - deadline == lateness`` exactly and a consumer can always
tell which slot a sample belongs to. Samples are handed over in blocks of
``block_size`` slots (fewer samples when some slots had none); a block also carries the
counts of every slot since the previous block, so ``on_time + late + missed + failed ==
slot_end - slot_begin`` per block.

Nothing here knows about processes or sockets: the clock and the sink are injected,
which is how the tests drive the loop in virtual time.
"""

from __future__ import annotations

import gc
import logging
import time
from array import array
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

from fluidsense.common.errors import ConfigError, DeviceProtocolError

from .poller import NoNewSample, Poller

log = logging.getLogger(__name__)


class Clock(Protocol):
    """Time source of the loop, in integer nanoseconds of a monotonic clock."""

    def now_ns(self) -> int: ...

    def wait_until_ns(self, deadline_ns: int) -> None:
        """Return at or after ``deadline_ns`` (never before)."""


class SpinClock:
    """CLOCK_MONOTONIC. Sleeps until ``spin_ns`` before the deadline, then spins to it:
    the kernel's wake-up latency (about 100 us here without SCHED_FIFO) is absorbed by
    the spin instead of landing on the sample."""

    def __init__(self, spin_ns: int = 200_000, now_ns: Callable[[], int] = time.monotonic_ns,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.spin_ns = int(spin_ns)
        self._now = now_ns
        self._sleep = sleep
        # the clock function itself, not a method around it: the loop stamps samples
        # with it right after the spin, where every call level costs ~100 ns
        self.now_ns = now_ns

    def wait_until_ns(self, deadline_ns: int) -> None:
        remaining = deadline_ns - self.spin_ns - self._now()
        if remaining > 0:
            self._sleep(remaining / 1e9)
        now = self._now
        while now() < deadline_ns:
            pass


@dataclass
class Counts:
    """How slots were filed. ``slots`` is their sum: every slot lands in one bin."""

    on_time: int = 0
    late: int = 0
    missed: int = 0
    failed: int = 0

    @property
    def slots(self) -> int:
        return self.on_time + self.late + self.missed + self.failed

    def add(self, other: Counts) -> None:
        self.on_time += other.on_time
        self.late += other.late
        self.missed += other.missed
        self.failed += other.failed

    def as_dict(self) -> dict[str, int]:
        return {"on_time": self.on_time, "late": self.late, "missed": self.missed,
                "failed": self.failed, "slots": self.slots}


@dataclass
class Block:
    """Samples of the slots ``[slot_begin, slot_end)`` that were read, with the counts of
    all those slots. ``t_s`` is the read time relative to slot 0's deadline (s),
    ``values`` is row-major (sample, channel) in SI units, ``lateness_s`` is
    ``t - deadline`` per sample. A block can be empty (only counts) when the loop ends
    after failed or missed slots."""

    seq: int
    slot_begin: int
    slot_end: int
    counts: Counts
    t_s: array
    values: array
    lateness_s: array
    read_max_s: float
    last_error: str | None = None
    #: (slot served, ns) for each re-alignment: how late the loop woke for the slot it
    #: was waiting for, the first of those it then missed (a stall, always >= 1 period)
    stalls: list[tuple[int, int]] = field(default_factory=list)
    #: reads that took longer than a period: among ``counts.missed``, no sample
    slow: int = 0

    def __len__(self) -> int:
        return len(self.t_s)


@dataclass
class LoopResult:
    """Why the loop ended, with the totals over every slot it went through."""

    reason: str  # "stopped", "link_lost" or "implausible"
    totals: Counts
    slots: int
    detail: str = ""
    blocks: int = 0
    field: str = ""  # "implausible": the field the device lied in


@dataclass
class _Accumulator:
    slot_begin: int
    counts: Counts = field(default_factory=Counts)
    t_s: array = field(default_factory=lambda: array("d"))
    values: array = field(default_factory=lambda: array("d"))
    lateness_s: array = field(default_factory=lambda: array("d"))
    read_max_ns: int = 0
    last_error: str | None = None
    stalls: list[tuple[int, int]] = field(default_factory=list)
    slow: int = 0


class SlotLoop:
    """Reads ``poller`` once per slot and hands blocks to ``emit``.

    ``emit`` is called synchronously from the loop and must return quickly (the next
    deadline is at most one period away); it receives a fresh Block each time.
    """

    def __init__(self, poller: Poller, clock: Clock, emit: Callable[[Block], None], *,
                 rate_hz: float, block_size: int, n_channels: int, late_threshold_ns: int,
                 max_consecutive_failures: int, link_timeout_ns: int = 0) -> None:
        if rate_hz <= 0 or block_size < 1 or n_channels < 1 or max_consecutive_failures < 1:
            raise ConfigError("slot loop: rate_hz > 0, block_size >= 1, n_channels >= 1 and "
                              "max_consecutive_failures >= 1 are required")
        self.poller = poller
        self.clock = clock
        self.emit = emit
        self.period_ns = 1e9 / rate_hz
        self.block_size = block_size
        self.n_channels = n_channels
        self.late_threshold_ns = late_threshold_ns
        self.max_failures = max_consecutive_failures
        self.link_timeout_ns = link_timeout_ns
        self._failing_since_ns = 0
        self._consecutive_slow = 0
        self._slow_since_ns = 0
        self.t0_ns = 0
        self.next_slot = 0
        self.totals = Counts()
        self._consecutive_failures = 0
        self._lost: str | None = None
        self._lie: DeviceProtocolError | None = None
        self._seq = 0
        self._acc = _Accumulator(0)

    def deadline_ns(self, k: int) -> int:
        # t0 + round(k * period): exact for integral periods, no drift for the others
        return self.t0_ns + round(k * self.period_ns)

    def run(self, should_stop: Callable[[], bool], t0_ns: int) -> LoopResult:
        """Serve slots from slot 0 at ``t0_ns`` until ``should_stop()`` is true (asked once
        per slot, right after the previous read) or the link is lost. The partial block
        is flushed before returning, so every slot gone through is in some block."""
        self.t0_ns = t0_ns
        # The stretch from the end of the wait to the read is the timing-critical one:
        # hot names are locals and the common case calls nothing but the clock.
        wait, now, read = self.clock.wait_until_ns, self.clock.now_ns, self.poller.read
        k = 0
        while not self._lost and self._lie is None and not should_stop():
            deadline = self.deadline_ns(k)
            next_deadline = self.deadline_ns(k + 1)
            wait(deadline)
            t = now()
            if t >= next_deadline:
                k = self._realign(t, k)
                deadline = self.deadline_ns(k)
            try:
                raw = read()
                row = [float(x) for x in raw]
            except NoNewSample:
                self._acc.counts.missed += 1
            except DeviceProtocolError as exc:
                # the device said what cannot be true: nothing more it says can be trusted,
                # and the slot is failed, not a sample; the daemon reconnects
                self._acc.counts.failed += 1
                self._lie = exc
                log.error("slot %d: the device said what cannot be true: %s", k, exc)
            except Exception as exc:  # noqa: BLE001 - any read failure is a failed slot
                self._failed(k, t, exc)
            else:
                read_ns = now() - t
                if read_ns > self.period_ns:
                    self._slow_read(k, t, read_ns)
                else:
                    self._sample(k, t, t - deadline, row, read_ns)
            k += 1
            self.next_slot = k
            # a block is block_size slots, not block_size samples: slots without a sample
            # (failed, missed) must not hold the samples before them back (a failing link
            # once delivered 0.25 s old samples at its end, which read as an overrun)
            if k - self._acc.slot_begin >= self.block_size:
                self._emit(k)
        self._flush()
        if self._lost:
            return LoopResult("link_lost", self.totals, self.next_slot, self._lost, self._seq)
        if self._lie is not None:
            return LoopResult("implausible", self.totals, self.next_slot, str(self._lie), self._seq, self._lie.field)
        return LoopResult("stopped", self.totals, self.next_slot, "", self._seq)

    def _realign(self, t: int, k: int) -> int:
        """The loop woke after slot k+1's deadline: slots k..j-1 are missed, and j, the
        newest slot whose deadline has passed, is served now (late, never twice)."""
        j = max(k + 1, int((t - self.t0_ns) // self.period_ns))
        while self.deadline_ns(j + 1) <= t:
            j += 1
        while j > k + 1 and self.deadline_ns(j) > t:
            j -= 1
        self._acc.counts.missed += j - k
        self._acc.stalls.append((j, t - self.deadline_ns(k)))
        return j

    def _slow_read(self, k: int, t: int, read_ns: int) -> None:
        """A read longer than a period: missed. Reads that stay that slow for the link's
        timeout mean this device cannot be sampled at this rate: link lost, saying so."""
        acc = self._acc
        acc.counts.missed += 1
        acc.slow += 1
        acc.read_max_ns = max(acc.read_max_ns, read_ns)
        self._consecutive_slow += 1
        if self._consecutive_slow == 1:
            self._slow_since_ns = t
            log.debug("slot %d: a read took %.2f ms, longer than the %.2f ms period: no sample", k, read_ns / 1e6,
                     self.period_ns / 1e6)
        slow_ns = t - self._slow_since_ns
        if self._consecutive_slow >= self.max_failures and slow_ns >= self.link_timeout_ns:
            self._lost = (f"every read for {slow_ns / 1e9:.3f} s took longer than the {self.period_ns / 1e6:.3g} ms "
                          f"period (last {read_ns / 1e6:.3g} ms): their samples cannot be timed; lower the rate")
            log.error("link lost at slot %d: %s", k, self._lost)

    def _sample(self, k: int, t: int, lateness_ns: int, row: list[float], read_ns: int) -> None:
        if len(row) != self.n_channels:
            raise ConfigError(f"poller {type(self.poller).__name__} returned {len(row)} values, "
                              f"the config names {self.n_channels} channel(s)")
        self._consecutive_slow = 0
        if self._consecutive_failures:
            log.info("reads recovered at slot %d after %d failed", k, self._consecutive_failures)
            self._consecutive_failures = 0
            # A poller's exceptions can hold cycles (chained exceptions, tracebacks and
            # frames) that nothing collects while gc is disabled: collect the young
            # generation once per failure episode, after this slot's read.
            gc.collect(0)
        acc = self._acc
        if lateness_ns > self.late_threshold_ns:
            acc.counts.late += 1
        else:
            acc.counts.on_time += 1
        acc.t_s.append((t - self.t0_ns) / 1e9)
        acc.values.extend(row)
        acc.lateness_s.append(lateness_ns / 1e9)
        if read_ns > acc.read_max_ns:
            acc.read_max_ns = read_ns

    def _failed(self, k: int, t: int, exc: Exception) -> None:
        # Keep only text: an exception object holds its traceback, whose frames hold
        # the loop, a reference cycle that nothing collects while gc is disabled.
        error = f"{type(exc).__name__}: {exc}"
        self._acc.counts.failed += 1
        self._acc.last_error = error
        self._consecutive_failures += 1
        if self._consecutive_failures == 1:
            self._failing_since_ns = t
            log.warning("read failed at slot %d: %s", k, error)
        failing_ns = t - self._failing_since_ns
        if self._consecutive_failures >= self.max_failures and failing_ns >= self.link_timeout_ns:
            self._lost = (f"{self._consecutive_failures} consecutive failed reads over {failing_ns / 1e9:.3f} s, "
                          f"last: {error}")
            log.error("link lost at slot %d: %s", k, self._lost)

    def _flush(self) -> None:
        if self.next_slot > self._acc.slot_begin:
            self._emit(self.next_slot)

    def _emit(self, slot_end: int) -> None:
        acc = self._acc
        self._acc = _Accumulator(slot_end)
        self.totals.add(acc.counts)
        block = Block(self._seq, acc.slot_begin, slot_end, acc.counts, acc.t_s, acc.values,
                      acc.lateness_s, acc.read_max_ns / 1e9, acc.last_error, acc.stalls, acc.slow)
        self._seq += 1
        self.emit(block)
