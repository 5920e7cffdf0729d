"""The recording's queue: the loop never waits on a slow disk in real time (it drops and
counts), loses nothing in virtual time, and hears of the sink's failure."""

from __future__ import annotations

import threading

import pytest
from fluidsense.common.errors import RecordingError
from fluidsense.controller.telemetry.fanout import Sink
from fluidsense.controller.telemetry.queued import QueuedSink


class Gate(Sink):
    """A sink stuck on its disk until the test opens the gate."""

    def __init__(self, fail_on: str | None = None):
        self.gate, self.seen, self.closed, self.fail_on = threading.Event(), [], False, fail_on

    def on_event(self, topic, t_s, payload):
        self.gate.wait()
        if topic == self.fail_on:
            raise RecordingError("disk full")
        self.seen.append(topic)

    def close(self):
        self.closed = True


def test_real_time_drops_and_counts_what_does_not_fit_and_keeps_the_rest_in_order():
    inner = Gate()
    sink = QueuedSink(inner, wait_when_full=False, maxsize=5)
    for i in range(20):  # the first may already be in the sink's hands, five wait in the queue
        sink.on_event(f"e{i}", float(i), {})
    assert 14 <= sink.dropped <= 15 and sink.stats["dropped"] == sink.dropped
    inner.gate.set()
    sink.close()
    assert inner.closed and len(inner.seen) == 20 - sink.dropped
    assert inner.seen == sorted(inner.seen, key=lambda s: int(s[1:]))  # order kept


def test_virtual_time_waits_for_the_sink_and_loses_nothing():
    inner = Gate()
    sink = QueuedSink(inner, wait_when_full=True, maxsize=2)
    producer = threading.Thread(target=lambda: [sink.on_event(f"e{i}", float(i), {}) for i in range(50)])
    producer.start()
    inner.gate.set()
    producer.join()
    sink.close()
    assert sink.dropped == 0 and inner.seen == [f"e{i}" for i in range(50)]


def test_a_failing_sink_is_reported_at_the_next_call():
    inner = Gate(fail_on="bad")
    inner.gate.set()
    sink = QueuedSink(inner, wait_when_full=True, maxsize=2)
    sink.on_event("bad", 0.0, {})
    with pytest.raises(RecordingError, match="disk full"):
        for i in range(10_000):  # the thread fails soon; every call after that raises
            sink.on_event(f"e{i}", float(i), {})
    sink.close()  # nothing left to report, and it returns


def test_the_sink_thread_runs_at_the_sample_loops_real_time_priority():
    """The loop's thread at SCHED_FIFO resets the policy of the threads it starts (they are
    clones: SCHED_RESET_ON_FORK); the recording's thread, which takes the GIL and the
    queue's lock the loop takes, asks for the loop's priority back. In a fresh process,
    as the daemon sets it; skipped where real-time priority is refused."""
    import subprocess
    import sys

    code = (
        "import os, threading\n"
        "from fluidsense.drivers.sampler.realtime import set_loop_priority\n"
        "from fluidsense.controller.telemetry.fanout import Sink\n"
        "from fluidsense.controller.telemetry.queued import QueuedSink\n"
        "granted = set_loop_priority(7)['applied']\n"
        "seen = []\n"
        "class Probe(Sink):\n"
        "    def on_event(self, topic, t_s, payload):\n"
        "        policy = os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK\n"
        "        seen.append((policy, os.sched_getparam(0).sched_priority))\n"
        "plain = []\n"
        "t = threading.Thread(target=lambda: plain.append(os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK))\n"
        "t.start(); t.join()\n"
        "sink = QueuedSink(Probe(), wait_when_full=True)\n"
        "sink.on_event('probe', 0.0, {})\n"
        "sink.close()\n"
        "print(granted, plain[0] == os.SCHED_OTHER, seen[0] == (os.SCHED_FIFO, 7))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    if out[0] == "False":
        pytest.skip("SCHED_FIFO is refused here (no CAP_SYS_NICE or RLIMIT_RTPRIO)")
    # a thread of its own is reset to normal priority; the sink's thread takes the loop's
    assert out == ["True", "True", "True"], out
