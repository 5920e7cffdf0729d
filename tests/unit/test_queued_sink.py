"""The recording's queue: the loop never waits on a slow disk in real time (it drops and
counts), loses nothing in virtual time, and hears of the sink's failure.

(Its tests with real peers: tests/system/test_queued_sink.py.)
"""

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
