"""The sampler's slot loop in virtual time: late, missed and failed slots are injected at
known places, and the counts, lateness values, timestamps and block boundaries must be
exactly what was injected. No wall clock anywhere."""

from __future__ import annotations

import errno
import logging

import pytest
from fluidsense.common.errors import ConfigError
from fluidsense.drivers.sampler import realtime
from fluidsense.drivers.sampler.poller import NoNewSample
from fluidsense.drivers.sampler.slots import Block, SlotLoop, SpinClock
from fluidsense.drivers.sampler.synthetic import SyntheticPoller
from hypothesis import given, settings
from hypothesis import strategies as st

P = 1_000_000  # ns: 1 kHz
T0 = 5_000_000_000


def d(k: int) -> int:
    """Deadline of slot k."""
    return T0 + k * P


class FakeClock:
    """Virtual time: waiting jumps to the deadline plus the delay injected for it."""

    def __init__(self, delays: dict[int, int] | None = None) -> None:
        self.t = 0
        self.delays = dict(delays or {})
        self.waits: list[int] = []

    def now_ns(self) -> int:
        return self.t

    def wait_until_ns(self, deadline_ns: int) -> None:
        self.waits.append(deadline_ns)
        self.t = max(self.t, deadline_ns) + self.delays.pop(deadline_ns, 0)


class FakePoller:
    """Read n returns (n,), takes ``durations[n]`` of virtual time, raises if n in ``fail``."""

    def __init__(self, clock: FakeClock, durations: dict[int, int] | None = None, fail=(), channels: int = 1,
                 stale=()):
        self.clock = clock
        self.durations = durations or {}
        self.fail = set(fail)
        self.stale = set(stale)  # reads that find nothing new at the source
        self.channels = channels
        self.read_times: list[int] = []

    def open(self) -> None: ...

    def close(self) -> None: ...

    def read(self) -> tuple[float, ...]:
        n = len(self.read_times)
        self.read_times.append(self.clock.t)
        self.clock.t += self.durations.get(n, 0)
        if n in self.fail:
            raise ConnectionError(f"read {n} failed")
        if n in self.stale:
            raise NoNewSample
        return tuple(float(n) for _ in range(self.channels))


def run_loop(slots: int, *, delays=None, durations=None, fail=(), block_size=10, threshold_ns=50_000,
             max_failures=10, rate_hz=1000.0, channels=1, stale=(), link_timeout_ns=0):
    clock = FakeClock(delays)
    poller = FakePoller(clock, durations, fail, channels, stale)
    blocks: list[Block] = []
    loop = SlotLoop(poller, clock, blocks.append, rate_hz=rate_hz, block_size=block_size, n_channels=channels,
                    late_threshold_ns=threshold_ns, max_consecutive_failures=max_failures,
                    link_timeout_ns=link_timeout_ns)
    result = loop.run(lambda: loop.next_slot >= slots, T0)
    return result, blocks, poller, clock


def samples(blocks: list[Block]):
    t = [x for b in blocks for x in b.t_s]
    lat = [x for b in blocks for x in b.lateness_s]
    v = [x for b in blocks for x in b.values]
    return t, lat, v


def assert_blocks_account_for_every_slot(blocks: list[Block], slots: int) -> None:
    assert blocks[0].slot_begin == 0 and blocks[-1].slot_end == slots
    for a, b in zip(blocks, blocks[1:]):
        assert b.slot_begin == a.slot_end
    for b in blocks:
        assert b.counts.slots == b.slot_end - b.slot_begin
        assert b.counts.on_time + b.counts.late == len(b)


def test_all_on_time_blocks_and_exact_timestamps():
    result, blocks, poller, clock = run_loop(25)
    assert result.reason == "stopped" and result.slots == 25
    assert result.totals.as_dict() == {"on_time": 25, "late": 0, "missed": 0, "failed": 0, "slots": 25}
    assert [len(b) for b in blocks] == [10, 10, 5]
    assert [(b.slot_begin, b.slot_end) for b in blocks] == [(0, 10), (10, 20), (20, 25)]
    t, lat, v = samples(blocks)
    assert t == [k * P / 1e9 for k in range(25)]
    assert lat == [0.0] * 25
    assert v == [float(n) for n in range(25)]
    assert clock.waits == [d(k) for k in range(25)]


def test_late_slots_are_counted_with_their_lateness_and_stamped_when_read():
    # 50 us is the threshold itself: on time; 50.001 us is late; 999.999 us is late, not missed
    delays = {d(3): 80_000, d(7): 50_000, d(8): 50_001, d(12): 999_999}
    result, blocks, poller, _ = run_loop(20, delays=delays)
    assert result.totals.as_dict() == {"on_time": 17, "late": 3, "missed": 0, "failed": 0, "slots": 20}
    t, lat, _ = samples(blocks)
    for k in range(20):
        injected = delays.get(d(k), 0)
        assert lat[k] == injected / 1e9
        assert t[k] == (k * P + injected) / 1e9  # the time of the read, not the deadline
        assert poller.read_times[k] == d(k) + injected
    assert [b.counts.late for b in blocks] == [2, 1]


def test_a_late_wake_past_the_next_deadline_misses_slots_and_realigns_without_bursting():
    # the wait for slot 5 returns at 7.3 ms: slots 5 and 6 are missed, 7 is served 300 us late
    result, blocks, poller, clock = run_loop(12, delays={d(5): 2_300_000})
    assert result.totals.as_dict() == {"on_time": 9, "late": 1, "missed": 2, "failed": 0, "slots": 12}
    t, lat, v = samples(blocks)
    slots_served = [0, 1, 2, 3, 4, 7, 8, 9, 10, 11]
    assert t == [(k * P + (300_000 if k == 7 else 0)) / 1e9 for k in slots_served]
    assert lat[5] == 300_000 / 1e9 and lat[6] == 0.0
    # one read per served slot, and the loop then waits for slot 8's deadline: no catch-up burst
    assert poller.read_times == [d(k) + (300_000 if k == 7 else 0) for k in slots_served]
    assert clock.waits == [d(k) for k in range(6)] + [d(k) for k in range(8, 12)]
    # blocks of 10 slots: the first holds the 8 samples of its slots, the rest at the end
    assert [(b.slot_begin, b.slot_end, len(b)) for b in blocks] == [(0, 10, 8), (10, 12, 2)]
    assert blocks[0].stalls == [(7, 2_300_000)]  # woke 2.3 ms after the deadline it waited for


def test_waking_exactly_on_the_next_deadline_misses_one_slot():
    result, blocks, _, _ = run_loop(8, delays={d(4): P})
    assert result.totals.as_dict() == {"on_time": 7, "late": 0, "missed": 1, "failed": 0, "slots": 8}
    t, lat, _ = samples(blocks)
    assert t == [k * P / 1e9 for k in (0, 1, 2, 3, 5, 6, 7)] and lat == [0.0] * 7
    assert blocks[0].stalls == [(5, P)]


def test_a_slow_read_makes_the_following_slots_missed_or_late():
    # read 3 takes 2.5 ms: its value is from some moment of those 2.5 ms, so slot 3 gives no
    # sample (missed, and slow); slot 4 is missed, slot 5 is served at 5.5 ms (500 us late)
    result, blocks, poller, _ = run_loop(10, durations={3: 2_500_000})
    assert result.totals.as_dict() == {"on_time": 7, "late": 1, "missed": 2, "failed": 0, "slots": 10}
    t, lat, _ = samples(blocks)
    assert t[:4] == [0.0, P / 1e9, 2 * P / 1e9, (5 * P + 500_000) / 1e9] and lat[3] == 500_000 / 1e9
    assert blocks[0].slow == 1 and blocks[0].read_max_s == 2_500_000 / 1e9
    assert blocks[0].stalls == [(5, 1_500_000)]  # waiting for slot 4 ended at 5.5 ms


def test_reads_that_stay_slower_than_a_period_are_a_lost_link_that_says_why():
    """A device that cannot answer within a period cannot be sampled at this rate: every
    slot missed, then link lost naming the read time, not a silent stream of nothing."""
    slow = {n: 1_200_000 for n in range(100)}
    result, blocks, _, _ = run_loop(100, durations=slow, max_failures=5, link_timeout_ns=20 * P)
    assert result.reason == "link_lost"
    assert "took longer than the 1 ms period (last 1.2 ms)" in result.detail
    assert sum(len(b) for b in blocks) == 0 and result.totals.on_time == 0
    # one slow read among quick ones is only a missed slot
    result, blocks, _, _ = run_loop(100, durations={40: 1_200_000}, max_failures=5, link_timeout_ns=20 * P)
    assert result.reason == "stopped" and sum(b.slow for b in blocks) == 1


def test_block_boundaries_carry_the_counts_of_their_own_slots():
    # block_size 4; slot 3 late, slots 6-8 missed (woke 3.2 ms after slot 6's deadline), read 11 fails
    delays = {d(3): 70_000, d(6): 3_200_000}
    result, blocks, _, _ = run_loop(20, delays=delays, fail={8}, block_size=4)
    # reads: slots 0-5 -> reads 0-5, slot 9 -> read 6, slot 10 -> read 7, slot 11 -> read 8 (fails).
    # A block ends once it spans 4 slots (more when a stall jumps over its end), whatever
    # they held: samples never wait for slots that have none
    assert [(b.slot_begin, b.slot_end) for b in blocks] == [(0, 4), (4, 10), (10, 14), (14, 18), (18, 20)]
    assert [b.counts.as_dict() for b in blocks] == [
        {"on_time": 3, "late": 1, "missed": 0, "failed": 0, "slots": 4},
        {"on_time": 2, "late": 1, "missed": 3, "failed": 0, "slots": 6},  # slot 9 is 200 us late
        {"on_time": 3, "late": 0, "missed": 0, "failed": 1, "slots": 4},
        {"on_time": 4, "late": 0, "missed": 0, "failed": 0, "slots": 4},
        {"on_time": 2, "late": 0, "missed": 0, "failed": 0, "slots": 2},
    ]
    assert blocks[2].last_error == "ConnectionError: read 8 failed"
    assert_blocks_account_for_every_slot(blocks, 20)
    assert result.totals.as_dict() == {"on_time": 14, "late": 2, "missed": 3, "failed": 1, "slots": 20}


def test_failed_reads_are_counted_and_do_not_produce_samples():
    result, blocks, _, _ = run_loop(15, fail={2, 3, 9})
    assert result.reason == "stopped"
    assert result.totals.as_dict() == {"on_time": 12, "late": 0, "missed": 0, "failed": 3, "slots": 15}
    t, _, v = samples(blocks)
    assert t == [k * P / 1e9 for k in range(15) if k not in (2, 3, 9)]
    assert v == [float(k) for k in range(15) if k not in (2, 3, 9)]


def test_link_loss_after_n_consecutive_failures_flushes_the_partial_block():
    # reads 3 and 4 fail (2 in a row, below N=3), then reads 10.. fail: lost at read 12
    result, blocks, poller, _ = run_loop(100, fail={3, 4, *range(10, 100)}, max_failures=3, block_size=4)
    assert result.reason == "link_lost" and result.slots == 13
    assert result.detail == "3 consecutive failed reads over 0.002 s, last: ConnectionError: read 12 failed"
    assert result.totals.as_dict() == {"on_time": 8, "late": 0, "missed": 0, "failed": 5, "slots": 13}
    assert len(poller.read_times) == 13
    assert_blocks_account_for_every_slot(blocks, 13)
    assert len(blocks[-1]) == 0 and blocks[-1].counts.failed == 1  # the accounting-only tail: slot 12
    assert [len(b) for b in blocks] == [3, 3, 2, 0]  # the samples before the failures came out at once


def test_link_loss_takes_failures_lasting_the_link_timeout_not_a_count():
    """At 1 kHz ten failed slots are 10 ms: a busy box. The link is lost only once reads
    have failed in a row for link_timeout_ns (here 50 ms): a 30 ms burst of failures
    costs its slots and nothing more."""
    burst, lasting = set(range(10, 40)), set(range(60, 200))
    result, blocks, _, _ = run_loop(200, fail=burst | lasting, max_failures=2, link_timeout_ns=50 * P)
    assert result.reason == "link_lost" and result.slots == 111  # slots 60..110: 50 ms of failures
    assert result.detail.startswith("51 consecutive failed reads over 0.050 s")
    assert result.totals.failed == 30 + 51 and result.totals.on_time == 111 - 81


def test_a_read_with_nothing_new_is_a_missed_slot_never_a_repeated_value():
    result, blocks, _, _ = run_loop(50, stale={5, 6, 7, 20}, link_timeout_ns=3 * P, max_failures=2)
    assert result.reason == "stopped"  # however long it lasts, nothing new is not a failure
    _, _, values = samples(blocks)  # one channel: one value per sample
    assert result.totals.as_dict() == {"on_time": 46, "late": 0, "missed": 4, "failed": 0, "slots": 50}
    assert values == [float(n) for n in range(50) if n not in {5, 6, 7, 20}]
    assert_blocks_account_for_every_slot(blocks, 50)


def test_a_poller_returning_the_wrong_number_of_values_is_a_config_error():
    with pytest.raises(ConfigError, match="returned 2 values, the config names 1 channel"):
        clock = FakeClock()
        loop = SlotLoop(FakePoller(clock, channels=2), clock, lambda b: None, rate_hz=1000, block_size=10,
                        n_channels=1, late_threshold_ns=50_000, max_consecutive_failures=3)
        loop.run(lambda: False, T0)


def test_deadlines_of_a_non_integral_period_do_not_drift():
    loop = SlotLoop(SyntheticPoller(), FakeClock(), lambda b: None, rate_hz=3000, block_size=1, n_channels=1,
                    late_threshold_ns=50_000, max_consecutive_failures=1)
    loop.t0_ns = T0
    assert loop.deadline_ns(3000) == T0 + 1_000_000_000
    assert loop.deadline_ns(3 * 10**7) == T0 + 10**13
    assert [loop.deadline_ns(k) - T0 for k in range(4)] == [0, 333_333, 666_667, 1_000_000]


def test_synthetic_poller_signal_and_failures():
    p = SyntheticPoller(channels=2, offset_pa=100.0, amplitude_pa=10.0, cycle_reads=4, fail_reads=[1], fail_from=5)
    p.open()
    assert p.read() == pytest.approx((100.0, 100.0))
    with pytest.raises(ConnectionError, match="read 1"):
        p.read()
    assert p.read() == p.expected(2) == pytest.approx((100.0, 100.0))
    assert p.read() == pytest.approx((90.0, 110.0))
    p.read()
    with pytest.raises(ConnectionError, match="read 5"):
        p.read()
    with pytest.raises(ConnectionRefusedError, match="nope"):
        SyntheticPoller(open_error="nope").open()


# ----------------------------------------------------------------- the real clock's logic
class ScriptedTime:
    """A time source that advances 1 us per reading, and a sleep that oversleeps."""

    def __init__(self, oversleep_ns: int) -> None:
        self.t = 0
        self.oversleep_ns = oversleep_ns
        self.sleeps: list[float] = []

    def now(self) -> int:
        self.t += 1_000
        return self.t

    def sleep(self, s: float) -> None:
        self.sleeps.append(s)
        self.t += round(s * 1e9) + self.oversleep_ns


@pytest.mark.parametrize("oversleep_ns", [0, 150_000, 400_000])
def test_spin_clock_sleeps_to_the_margin_then_spins_and_never_returns_early(oversleep_ns):
    ts = ScriptedTime(oversleep_ns)
    clock = SpinClock(spin_ns=200_000, now_ns=ts.now, sleep=ts.sleep)
    clock.wait_until_ns(1_000_000)
    assert ts.sleeps == [(1_000_000 - 200_000 - 1_000) / 1e9]
    assert ts.t >= 1_000_000
    # an oversleep beyond the margin is returned as is: the loop records it as lateness
    if oversleep_ns > 200_000:
        assert ts.t - 1_000_000 >= oversleep_ns - 200_000
    else:
        assert ts.t - 1_000_000 <= 1_000
    # a deadline already passed: no sleep at all
    clock.wait_until_ns(ts.t - 5)
    assert len(ts.sleeps) == 1


# ----------------------------------------------------------------- every slot, whatever happens
events = st.lists(st.tuples(st.integers(0, 40), st.sampled_from([0, 10_000, 60_000, 900_000, 1_000_000, 2_700_000]),
                            st.sampled_from([0, 0, 200_000, 1_500_000]), st.booleans()), max_size=12)


@settings(max_examples=150, deadline=None)
@given(events=events, block_size=st.integers(1, 7), slots=st.integers(1, 45))
def test_every_slot_is_accounted_for_exactly_once(events, block_size, slots):
    delays = {d(k): delay for k, delay, _, _ in events}
    durations = {k: dur for k, _, dur, _ in events}
    fail = {k for k, _, _, f in events if f}
    result, blocks, poller, _ = run_loop(slots, delays=delays, durations=durations, fail=fail,
                                         block_size=block_size, max_failures=1000)
    assert result.slots >= slots and result.totals.slots == result.slots
    assert_blocks_account_for_every_slot(blocks, result.slots)
    slow = sum(b.slow for b in blocks)
    assert slow == sum(1 for n, dur in durations.items() if dur > P and n < len(poller.read_times) and n not in fail)
    assert len(poller.read_times) == result.totals.on_time + result.totals.late + result.totals.failed + slow
    t, lat, _ = samples(blocks)
    assert all(a < b for a, b in zip(t, t[1:]))  # strictly increasing
    served = [round((x - y) * 1e9) // P for x, y in zip(t, lat)]  # t - lateness is the slot's deadline
    assert all(round((x - y) * 1e9) % P == 0 for x, y in zip(t, lat))
    assert len(set(served)) == len(served)
    assert all(0 <= y < P / 1e9 for y in lat)
    # a stall precedes exactly the slots served after a gap that no failure explains
    stalls = [slot for b in blocks for slot, ns in b.stalls]
    assert sum(1 for _ in stalls) == len(set(stalls))
    assert all(ns >= P for b in blocks for _, ns in b.stalls)


# ----------------------------------------------------------------- real-time settings
def test_a_refused_setting_logs_one_line_saying_what_and_why(monkeypatch, caplog):
    def refuse(*args):
        raise PermissionError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(realtime.os, "sched_setscheduler", refuse)
    monkeypatch.setattr(realtime.os, "sched_setaffinity", refuse)
    monkeypatch.setattr(realtime, "freeze_gc", lambda: realtime._result(True, "skipped in this test"))
    with caplog.at_level(logging.WARNING, logger="fluidsense.drivers.sampler.realtime"):
        report = realtime.apply(40, "auto")
    assert not report["sched_fifo"]["applied"] and not report["affinity"]["applied"]
    lines = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(lines) == 2
    assert any("sched_fifo not applied: SCHED_FIFO priority 40 refused: Operation not permitted (EPERM)" in m
               for m in lines)
    assert any(m.startswith("affinity not applied: pinning to CPU") and "EPERM" in m for m in lines)


def test_settings_not_requested_are_not_warned_about(caplog, monkeypatch):
    monkeypatch.setattr(realtime, "freeze_gc", lambda: realtime._result(True, "skipped in this test"))
    with caplog.at_level(logging.WARNING, logger="fluidsense.drivers.sampler.realtime"):
        report = realtime.apply(None, "none")
    assert report["sched_fifo"] == {"applied": False, "requested": False,
                                    "detail": "not requested (rt_priority: null)"}
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]


def test_probe_checks_a_poller_in_this_process():
    from fluidsense.drivers.sampler.poller import probe

    spec = "fluidsense.drivers.sampler.synthetic:SyntheticPoller"
    rows = probe(spec, {"channels": 2}, 2, reads=3)
    assert rows == [SyntheticPoller(channels=2).expected(n) for n in range(3)]
    with pytest.raises(ConfigError, match="returned 2 values for 3 channel"):
        probe(spec, {"channels": 2}, 3)
    with pytest.raises(ConfigError, match="constructor failed: TypeError"):
        probe(spec, {"no_such_argument": 1}, 1)
    with pytest.raises(ConfigError, match="is not 'module:Class'"):
        probe("synthetic", {}, 1)
