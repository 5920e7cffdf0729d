"""The recording's queue: the loop never waits on a slow disk in real time (it drops and
counts), loses nothing in virtual time, and hears of the sink's failure.

(Its in-process tests: tests/unit/test_queued_sink.py.)
"""

from __future__ import annotations

import pytest


def test_the_sink_thread_runs_at_the_sample_loops_real_time_priority():
    """The loop's thread at SCHED_FIFO resets the policy of the threads it starts (they are
    clones: SCHED_RESET_ON_FORK); the recording's thread, which takes the GIL and the
    queue's lock the loop takes, asks for the loop's priority back. In a fresh process,
    as the daemon sets it; skipped where real-time priority is refused. Released
    (release_loop_priority, as tests/support/harness.py's daemon_loop_priority does), the
    thread and the threads it starts are at normal priority again."""
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
        "from fluidsense.drivers.sampler.realtime import release_loop_priority\n"
        "release_loop_priority()\n"
        "again = QueuedSink(Probe(), wait_when_full=True)\n"
        "again.on_event('probe', 0.0, {})\n"
        "again.close()\n"
        "print(granted, plain[0] == os.SCHED_OTHER, seen[0] == (os.SCHED_FIFO, 7),\n"
        "      os.sched_getscheduler(0) == os.SCHED_OTHER and seen[1] == (os.SCHED_OTHER, 0))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    if out[0] == "False":
        pytest.skip("SCHED_FIFO is refused here (no CAP_SYS_NICE or RLIMIT_RTPRIO)")
    # a thread of its own is reset to normal priority; the sink's thread takes the loop's;
    # released (a library caller done with its loop), the thread and a later sink's are normal
    assert out == ["True", "True", "True", "True"], out
