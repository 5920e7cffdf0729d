"""Run the emulator as a subprocess (tests, tools): start it, wait for its ready line,
talk to its sim control channel, stop it.

.. code-block:: python

    with EmulatorProcess("127.0.0.7", modbus_port=5020) as box:
        box.set(protective_stop=True)
        assert box.state()["safety_mode"] == "PROTECTIVE_STOP"

Every wait has a timeout; nothing here imports ur_rtde.
"""

from __future__ import annotations

import json
import os
import random
import select
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from fluidsense.common.errors import DeviceTimeoutError, DriverError, LinkLostError


class EmulatorProcess:
    """``python -m fluidsense.simulator.controlbox`` in a child process."""

    def __init__(self, host: str = "127.0.0.1", *, modbus_port: int = 502, model: str | None = None,
                 args: Sequence[str] = (), python: str = sys.executable, cwd: Path | None = None,
                 command: Sequence[str] | None = None):
        """``command`` replaces the whole command line (e.g. ``fluidsense simcell``, which
        speaks the same ready line and sim control channel)."""
        self.host = host
        self.modbus_port = modbus_port
        self.argv = [python, "-m", "fluidsense.simulator.controlbox", "--host", host, "--modbus-port", str(modbus_port)]
        if model is not None:
            self.argv += ["--model", model]
        self.argv += list(args)
        if command is not None:
            self.argv = list(command)
        self.cwd = cwd
        self.proc: subprocess.Popen[bytes] | None = None
        self.ready_line = ""
        self._buffer = b""
        self._stderr = tempfile.TemporaryFile()
        self._final_log = ""

    # -- life ---------------------------------------------------------------------------------
    def start(self, timeout_s: float = 30.0) -> EmulatorProcess:
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.proc = subprocess.Popen(self.argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=self._stderr, cwd=self.cwd, env=env)
        line = self._readline(timeout_s, "the ready line")
        if not line.startswith("ready"):
            self.stop()
            raise DriverError(f"emulator said {line!r} instead of ready; log:\n{self.log()}")
        self.ready_line = line
        return self

    def stop(self, timeout_s: float = 10.0) -> int:
        """SIGTERM, then SIGKILL after ``timeout_s``; the exit code."""
        proc = self.proc
        if proc is None:
            return 0
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            code = proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            code = proc.wait()
        for stream in (proc.stdin, proc.stdout):
            if stream is not None:
                stream.close()
        return code

    def kill(self) -> int:
        """SIGKILL: the box vanishes without closing its sockets (peer-death tests)."""
        assert self.proc is not None
        self.proc.kill()
        code = self.proc.wait()
        for stream in (self.proc.stdin, self.proc.stdout):  # as stop() does: a dropped pipe is a ResourceWarning
            if stream is not None:
                stream.close()
        return code

    def __enter__(self) -> EmulatorProcess:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
        self._final_log = self.log()
        self._stderr.close()

    @property
    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def log(self) -> str:
        """Everything the emulator logged so far (its stderr)."""
        if self._stderr.closed:
            return self._final_log
        self._stderr.flush()
        self._stderr.seek(0)
        return self._stderr.read().decode(errors="replace")

    # -- sim control channel --------------------------------------------------------------------
    def command(self, payload: dict[str, Any], timeout_s: float = 10.0) -> dict[str, Any]:
        if not self.alive:
            raise LinkLostError(f"emulator is not running; log:\n{self.log()}")
        assert self.proc is not None and self.proc.stdin is not None
        self.proc.stdin.write((json.dumps(payload) + "\n").encode())
        self.proc.stdin.flush()
        reply = json.loads(self._readline(timeout_s, f"the reply to {payload}"))
        if not reply.get("ok"):
            raise DriverError(f"emulator refused {payload}: {reply.get('error')}")
        return reply

    def state(self) -> dict[str, Any]:
        return self.command({"cmd": "state"})["state"]

    def set(self, **fields: Any) -> dict[str, Any]:
        return self.command({"cmd": "set", **fields})["state"]

    def network(self, up: bool) -> dict[str, Any]:
        """Pull (``up=False``) or plug back the box's network cable; the box runs on."""
        return self.command({"cmd": "network", "up": up})["state"]

    def wait_for(self, predicate: Callable[[dict[str, Any]], bool], timeout_s: float = 10.0,
                 what: str = "condition") -> dict[str, Any]:
        """Poll the state until ``predicate(state)``; the state that satisfied it."""
        deadline = time.monotonic() + timeout_s
        while True:
            state = self.state()
            if predicate(state):
                return state
            if time.monotonic() > deadline:
                raise DeviceTimeoutError(f"{what} not reached within {timeout_s} s; last state: {state}")
            time.sleep(0.01)  # poll interval, not a timing assumption

    # -- internals -------------------------------------------------------------------------------
    def _readline(self, timeout_s: float, what: str) -> str:
        assert self.proc is not None and self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        deadline = time.monotonic() + timeout_s
        while b"\n" not in self._buffer:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise DeviceTimeoutError(f"emulator: no {what} within {timeout_s} s; log:\n{self.log()}")
            ready, _, _ = select.select([fd], [], [], remaining)
            if ready:
                chunk = os.read(fd, 65536)
                if not chunk:
                    code = self.proc.wait()
                    raise LinkLostError(f"emulator exited ({code}) before {what}; log:\n{self.log()}")
                self._buffer += chunk
        line, _, self._buffer = self._buffer.partition(b"\n")
        return line.decode(errors="replace")


#: the ports ``fluidsense simcell`` listens on: RTDE, dashboard, script, Modbus, sim control
SIMCELL_PORTS = (30004, 29999, 30003, 5020, 30010)
_rng = random.Random()


def _bindable(host: str, port: int) -> bool:
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def free_loopback(ports: Sequence[int] = SIMCELL_PORTS) -> str:
    """A 127.0.0.x address on which every one of ``ports`` is free: ur_rtde's ports are
    fixed, and other boxes (other tests, other sessions) run on this machine."""
    for _ in range(500):
        host = f"127.0.0.{_rng.randint(20, 250)}"
        if all(_bindable(host, p) for p in ports):
            return host
    raise DriverError("no free 127.0.0.x address")

