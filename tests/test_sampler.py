"""Sampler: exact slot accounting with an injected clock; the real process, invariants only."""

from __future__ import annotations

import asyncio
import os
import signal

import numpy as np
import pytest

from drivers.errors import LinkLostError
from drivers.sampler.config import PollerSpec, SamplerConfig
from drivers.sampler.loop import Block, SlotLoop
from drivers.sampler.source import SampledSource

P = 1_000_000  # 1 kHz period, ns


class FakeClock:
    """Wakes exactly at each deadline plus a scripted lateness (slot index -> ns)."""

    def __init__(self, t0: int, lateness: dict[int, int] | None = None):
        self.t = t0
        self.t0 = t0
        self.lateness = lateness or {}

    def now_ns(self) -> int:
        return self.t

    def sleep_until(self, deadline: int) -> None:
        k = round((deadline - self.t0) / P)
        self.t = max(self.t, deadline + self.lateness.get(k, 0))


def run_loop(lateness=None, n=100, block=10, threshold=100_000, read=None, max_failures=10):
    clock = FakeClock(10 * P, lateness)
    blocks: list[Block] = []
    counter = iter(range(10**9))
    loop = SlotLoop(clock, P, read or (lambda: (float(next(counter)),)), blocks.append, block, threshold, max_failures)
    loop.run(max_slots=n, t0_ns=10 * P)
    return blocks, loop


def test_on_time_slots_are_timestamped_at_their_deadlines():
    blocks, loop = run_loop()
    t = np.concatenate([b.arrays(1)[0] for b in blocks])
    assert len(blocks) == 10 and all(len(b.t_ns) == 10 for b in blocks)
    np.testing.assert_array_equal(t, 10 * P + np.arange(100) * P)
    assert (loop.totals.on_time, loop.totals.late, loop.totals.missed, loop.totals.failed) == (100, 0, 0, 0)


def test_injected_late_slots_are_counted_with_their_lateness():
    blocks, loop = run_loop({3: 150_000, 17: 90_000, 42: 999_000})
    t = np.concatenate([b.arrays(1)[0] for b in blocks])
    late = np.concatenate([b.arrays(1)[2] for b in blocks])
    assert loop.totals.late == 2 and loop.totals.on_time == 98 and loop.totals.missed == 0
    assert late[3] == 150_000 and late[17] == 90_000 and late[42] == 999_000
    assert t[3] == 10 * P + 3 * P + 150_000  # the real read time, not the deadline
    assert blocks[0].late == 1 and blocks[4].late == 1 and blocks[1].late == 0  # per block


def test_a_long_stall_misses_slots_and_the_loop_realigns_without_bursting():
    # waking 3.4 periods after slot 20's deadline: slots 20, 21, 22 are gone, slot 23 is read 0.4 P late
    blocks, loop = run_loop({20: 3 * P + 400_000})
    t = np.concatenate([b.arrays(1)[0] for b in blocks])
    tot = loop.totals
    assert tot.missed == 3 and tot.late == 1 and tot.on_time == 96
    assert tot.on_time + tot.late + tot.missed + tot.failed == 100
    assert len(t) == 97 and np.all(np.diff(t) > 0)
    k = np.round((t - 10 * P) / P).astype(int)
    assert 20 not in k and 21 not in k and 22 not in k and 23 in k  # no slot filled twice, none invented
    assert next(b for b in blocks if b.missed).missed == 3


def test_failed_reads_are_counted_and_n_in_a_row_is_link_loss():
    calls = {"n": 0}

    def flaky():
        calls["n"] += 1
        if calls["n"] in (5, 6) or calls["n"] >= 50:
            raise OSError("no reply")
        return (1.0,)

    blocks, loop = run_loop(read=flaky, max_failures=4)
    assert blocks[-1].link_lost is not None and "4 reads failed in a row" in blocks[-1].link_lost
    assert loop.totals.failed == 2 + 4 and loop.totals.on_time == 47


@pytest.fixture
def synthetic():
    def make(**kw):
        return SampledSource("test", SamplerConfig(rate_hz=1000, block_size=10, **kw),
                             PollerSpec(target="drivers.sampler.pollers:SyntheticPoller"), ("p_act",))
    return make


def test_the_real_process_accounts_for_every_slot(synthetic):
    async def body():
        src = synthetic()
        async with src:
            blocks = [await src.read_block() for _ in range(50)]
        return src, blocks

    src, blocks = asyncio.run(body())
    t = np.concatenate([b.t for b in blocks])
    assert np.all(np.diff(t) > 0)
    n_samples = len(t)
    tot = src.totals
    assert n_samples == tot["on_time"] + tot["late"]
    # slots elapsed between the first and last sample = samples + missed + failed in between
    slots = round((t[-1] - t[0]) * 1000) + 1
    assert abs(slots - (n_samples + sum(b.missed for b in blocks[1:]))) <= 1
    assert all(b.lateness_s is not None and len(b.lateness_s) == len(b.t) for b in blocks)
    assert not src.connected


def test_a_killed_sampler_is_link_loss(synthetic):
    async def body():
        src = synthetic(silence_timeout_s=2.0)
        async with src:
            await src.read_block()
            os.kill(src._proc.pid, signal.SIGKILL)
            with pytest.raises(LinkLostError, match="sampler"):
                for _ in range(1000):  # drain what it sent before it died
                    await src.read_block()
    asyncio.run(body())


def test_a_poller_that_keeps_failing_is_link_loss():
    async def body():
        src = SampledSource("flaky", SamplerConfig(rate_hz=1000, max_consecutive_failures=5),
                            PollerSpec(target="drivers.sampler.pollers:SyntheticPoller",
                                       kwargs={"fail_reads": list(range(30, 100))}), ("p_act",))
        async with src:
            with pytest.raises(LinkLostError, match="5 reads failed in a row"):
                for _ in range(100):
                    await src.read_block()
    asyncio.run(body())
