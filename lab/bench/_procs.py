"""Ending what a bench started: every process it starts ends with its scenario, whatever
went wrong in between (a bench that left daemons behind loaded every run after it)."""

from __future__ import annotations

import os
import signal
import subprocess


def end(proc: subprocess.Popen, timeout_s: float = 30.0, group: bool = False) -> int:
    """SIGTERM (to the process group with ``group``: the daemon's helpers too), then SIGKILL
    if it is still there after ``timeout_s``; waits, so nothing is left running or unreaped.
    Returns the exit code."""
    def send(sig: int) -> None:
        try:
            if group:
                os.killpg(proc.pid, sig)
            else:
                proc.send_signal(sig)
        except ProcessLookupError:
            pass  # ended meanwhile

    if proc.poll() is None:
        send(signal.SIGTERM)
        try:
            return proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            send(signal.SIGKILL)
    return proc.wait()
