"""The sampler process for real, at 1 kHz, with the synthetic poller. Only invariants are
asserted (this machine is shared and noisy): strictly increasing timestamps, every slot
accounted for once, a clean stop; and LinkLostError when the process dies or the link
is lost. Timeouts here only bound how long a broken test can hang.

(Its in-process tests: tests/unit/test_sampler_process.py.)
"""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from fluidsense.common.errors import ConfigError, DriverError, LinkLostError
from fluidsense.drivers.sampler import SampledSource, SamplerConfig
from fluidsense.drivers.sampler.synthetic import SyntheticPoller
from support.harness import REPO

SYNTHETIC = "fluidsense.drivers.sampler.synthetic:SyntheticPoller"


def config(**changes) -> SamplerConfig:
    data = {"poller": {"factory": SYNTHETIC, "kwargs": {"channels": 2, "amplitude_pa": 5000.0}},
            "channels": ["p_act", "p_tank"], "rate_hz": 1000, "block_size": 10,
            "silence_timeout_s": 10.0}
    data.update(changes)
    return SamplerConfig.model_validate(data)


def test_real_process_at_1khz_accounts_for_every_slot_and_stops_cleanly():
    cfg = config()
    period = 1 / cfg.rate_hz

    async def main():
        src = SampledSource(cfg)
        blocks = []
        async with src:
            assert set(src.hello["realtime"]) == {"sched_fifo", "affinity", "gc", "timerslack", "poller_threads"}
            for _ in range(60):  # about 0.6 s
                blocks.append(await src.read_block())
        return src, blocks

    src, blocks = asyncio.run(main())
    t = np.concatenate([b.t for b in blocks])
    lateness = np.concatenate([b.lateness_s for b in blocks])
    values = np.vstack([b.values for b in blocks])
    assert np.all(np.diff(t) > 0)
    assert np.all(lateness >= 0) and np.all(lateness < period)
    # t - lateness is the deadline of a grid slot, each slot at most once
    slots = np.round((t - lateness) / period)
    assert np.allclose(slots * period, t - lateness, rtol=0, atol=1e-9)
    assert np.all(np.diff(slots) >= 1)
    # the synthetic poller failed nothing: sample i is read i
    poller = SyntheticPoller(channels=2, amplitude_pa=5000.0)
    assert np.array_equal(values, np.array([poller.expected(i) for i in range(len(values))]))
    # per block: the missed count is exactly the gap in the slot grid before the block,
    # and each gap ends with a stall (the loop woke after the next slot's deadline)
    prev = -1
    after_gap = set()
    for b in blocks:
        s = np.round((b.t - b.lateness_s) / period).astype(int)
        assert b.missed == (s[0] - prev - 1) + int(np.sum(np.diff(s) - 1))
        assert b.late == int(np.sum(b.lateness_s > cfg.late_threshold_us * 1e-6))
        after_gap |= {int(x) for x, gap in zip(s, np.diff(np.concatenate([[prev], s]))) if gap > 1}
        prev = s[-1]
    assert {slot for slot, _ in src.stall_log if slot <= prev} == after_gap
    assert all(stall_s >= period for _, stall_s in src.stall_log)
    # the process's own totals: every slot in exactly one bin, and the same as what arrived
    final = src.final
    assert final["type"] == "stopped" and final["reason"] == "stop requested"
    totals = final["totals"]
    assert totals["on_time"] + totals["late"] + totals["missed"] + totals["failed"] == final["slots"]
    assert totals["failed"] == 0
    assert final["slots"] <= round(final["t_end_s"] / period) + 1
    assert src.stats["slots"] == final["slots"]
    assert src.stats["on_time"] + src.stats["late"] + src.stats["dropped"] == totals["on_time"] + totals["late"]
    assert src.stats["missed"] == totals["missed"]
    assert src.proc.returncode == 0
    assert not src.connected


def _read_until_lost(src: SampledSource, limit: int = 10_000):
    async def go():
        for _ in range(limit):
            await src.read_block()
        raise AssertionError("read_block() never raised")

    return go()


def test_killing_the_process_makes_read_block_raise_link_lost():
    async def main():
        src = SampledSource(config())
        async with src:
            await src.read_block()
            os.kill(src.pid, signal.SIGKILL)
            with pytest.raises(LinkLostError, match=r"exited \(killed by SIGKILL\)") as info:
                await _read_until_lost(src)
            assert isinstance(info.value.__cause__, ChildProcessError)
            with pytest.raises(LinkLostError):  # and it stays lost
                await src.read_block()
        assert src.proc.returncode == -signal.SIGKILL

    asyncio.run(main())


def test_sigterm_stops_the_process_cleanly_and_the_daemon_sees_link_lost():
    async def main():
        src = SampledSource(config())
        async with src:
            await src.read_block()
            os.kill(src.pid, signal.SIGTERM)
            with pytest.raises(LinkLostError, match=r"stopped on its own \(SIGTERM\)"):
                await _read_until_lost(src)
            assert src.final["type"] == "stopped"
            totals = src.final["totals"]
            assert totals["on_time"] + totals["late"] + totals["missed"] + totals["failed"] == src.final["slots"]
        assert src.proc.returncode == 0

    asyncio.run(main())


def test_reads_failing_for_the_link_timeout_mean_link_lost():
    """A failed read now and then is a missed slot; reads failing in a row for
    link_timeout_s (5 ms here: 5 slots at 1 kHz) end the link."""
    cfg = config(poller={"factory": SYNTHETIC, "kwargs": {"channels": 2, "fail_reads": [3], "fail_from": 25}},
                 link_timeout_s=0.005)

    async def main():
        src = SampledSource(cfg)
        async with src:
            with pytest.raises(LinkLostError, match=r"consecutive failed reads over 0\.00[5-9]") as info:
                await _read_until_lost(src)
            cause = info.value.__cause__
            assert isinstance(cause, DriverError) and "synthetic failure at read" in str(cause)
            assert src.final["type"] == "link_lost"
            failed = src.final["totals"]["failed"]
            assert failed >= 6  # the failure at read 3, then at least 5 slots' worth from read 25 on
            assert src.stats["failed"] == failed and src.stats["on_time"] + src.stats["late"] == 24
        assert src.proc.returncode == 4

    asyncio.run(main())


def test_a_bad_poller_spec_or_a_poller_that_cannot_open_fails_setup():
    async def main():
        with pytest.raises(ConfigError, match="no NoSuchPoller"):
            await SampledSource(config(poller={"factory": "fluidsense.drivers.sampler.synthetic:NoSuchPoller"})).setup()
        src = SampledSource(config(channels=["p_act"]))
        async with src:
            with pytest.raises(LinkLostError, match="returned 2 values, the config names 1 channel") as info:
                await _read_until_lost(src)
            assert isinstance(info.value.__cause__, ConfigError)
        bad_open = config(poller={"factory": SYNTHETIC, "kwargs": {"open_error": "connection refused by 10.0.0.9"}})
        with pytest.raises(LinkLostError, match="did not open: ConnectionRefusedError: connection refused"):
            await SampledSource(bad_open).setup()

    asyncio.run(main())


def test_the_sampler_exits_when_its_parent_dies(tmp_path):
    """SIGKILL of the daemon: its sampler exits (in about 10 ms) and removes the directory of
    the endpoints the daemon had bound, which nobody else is left to remove (a suite of
    daemons killed this way once left three such directories in /tmp per run)."""
    script = textwrap.dedent(f"""
        import asyncio, sys
        sys.path.insert(0, {str(REPO)!r})
        from fluidsense.drivers.sampler import SampledSource, SamplerConfig
        async def main():
            src = SampledSource(SamplerConfig(poller={{"factory": {SYNTHETIC!r}}}, channels=["p"]))
            await src.setup()
            await src.read_block()
            print(src.pid, src._dir, flush=True)
            await asyncio.sleep(3600)
        asyncio.run(main())
    """)
    parent = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True, cwd=REPO)
    try:
        pid, endpoints = parent.stdout.readline().split()
        pid = int(pid)
        assert os.path.exists(os.path.join(endpoints, "data"))
        parent.kill()
        parent.wait(30)
        for _ in range(600):  # at most 60 s; it normally takes about 10 ms
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                break
            if _is_zombie(pid):
                break
            time.sleep(0.1)
        else:
            os.kill(pid, signal.SIGKILL)
            raise AssertionError(f"sampler {pid} outlived its parent")
        assert not os.path.exists(endpoints), os.listdir(endpoints)
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait(30)
        parent.stdout.close()


def _is_zombie(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True


def test_a_silent_sampler_means_link_lost():
    async def main():
        src = SampledSource(config(silence_timeout_s=0.5))
        async with src:
            await src.read_block()
            os.kill(src.pid, signal.SIGSTOP)  # alive, but not a word any more
            try:
                with pytest.raises(LinkLostError, match="silent for 0.5 s") as info:
                    await _read_until_lost(src)
                assert isinstance(info.value.__cause__, TimeoutError)
            finally:
                os.kill(src.pid, signal.SIGCONT)
        assert src.proc.returncode == 0

    asyncio.run(main())
