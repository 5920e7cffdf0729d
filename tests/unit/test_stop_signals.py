"""The stop signals' exit codes (128 + the signal) and a second signal that does not cut the
unwinding short, in this process (common/stopsignals.py). (Each process that can move a
valve, stopped mid-cycle against the emulated box: tests/system/test_stop_signals.py.)"""

from __future__ import annotations

import asyncio
import logging
import os
import signal
import subprocess
import sys

import pytest
from fluidsense.common import stopsignals
from fluidsense.common.exitcodes import EXIT_HANGUP, EXIT_INTERRUPTED, EXIT_TERMINATED
from support.harness import REPO


def job(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "fluidsense", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=REPO, stdin=subprocess.DEVNULL,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})


def test_exit_codes_are_128_plus_the_signal():
    assert stopsignals.exit_code(signal.SIGTERM) == EXIT_TERMINATED == 143
    assert stopsignals.exit_code(signal.SIGHUP) == EXIT_HANGUP == 129
    assert stopsignals.exit_code(signal.SIGINT) == EXIT_INTERRUPTED == 130


def test_a_second_signal_does_not_cut_the_unwinding_short(caplog):
    """The job's clean-up (the controller's vent) runs to its end although more signals
    come during it (asyncio.run's own handler raised KeyboardInterrupt on a second Ctrl-C);
    the first signal is the one reported."""
    steps = []

    def ignored() -> int:
        return sum("while stopping on SIGTERM" in r.getMessage() for r in caplog.records)

    async def job():
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            await asyncio.Event().wait()  # until the signal cancels it
        finally:
            os.kill(os.getpid(), signal.SIGINT)
            os.kill(os.getpid(), signal.SIGHUP)
            for _ in range(10_000):  # loop iterations, bounded: each runs the handlers that are due
                if ignored() == 2:
                    break
                await asyncio.sleep(0)
            steps.append("vented")

    caplog.set_level(logging.WARNING, logger="fluidsense.common.stopsignals")
    with pytest.raises(stopsignals.StopSignal) as stopped:
        stopsignals.run(job())
    assert ignored() == 2 and steps == ["vented"]
    assert stopped.value.signum == signal.SIGTERM and stopped.value.exit_code == 143
    assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL  # the handlers are gone afterwards
