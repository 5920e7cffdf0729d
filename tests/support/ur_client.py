"""The real ur_rtde clients, each in a child process driven over JSON lines.

ur_rtde's constructors block forever on a silent server and hold the GIL while they do,
so no watchdog thread in the same process could ever fire: the client lives in a child,
and the parent (pytest, which never imports ur_rtde) waits for every answer with a
timeout and kills the child when it does not come.

Child: ``python -m tests.support.ur_client receive|io|control HOST JSON_ARGS`` prints
``{"ready": true}`` once the interface is constructed, then answers every
``{"call": NAME, "args": [...]}`` line with ``{"result": ...}`` or ``{"error": ...}``.
"""

from __future__ import annotations

import json
import os
import select
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[2]
_MODULES = {"receive": ("rtde_receive", "RTDEReceiveInterface"),
            "io": ("rtde_io", "RTDEIOInterface"),
            "control": ("rtde_control", "RTDEControlInterface")}


class ClientTimeout(AssertionError):
    """The client did not answer in time (it was killed)."""


class UrClient:
    """Parent side: one ur_rtde interface in a child process."""

    def __init__(self, kind: str, host: str, *args: Any, timeout_s: float = 20.0):
        """``args`` go to the interface's constructor after the host name."""
        self.kind, self.host = kind, host
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.proc = subprocess.Popen([sys.executable, "-m", "tests.support.ur_client", kind, host, json.dumps(args)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     cwd=REPO, env=env)
        self._buffer = b""
        self._pending = ""
        reply = self._read(timeout_s, f"{kind} constructor")
        if not reply.get("ready"):
            self.kill()
            raise AssertionError(f"{kind} interface failed: {reply.get('error')}; stderr:\n{self.stderr()}")

    def call(self, name: str, *args: Any, timeout_s: float = 20.0) -> Any:
        self.start_call(name, *args)
        return self.finish_call(timeout_s)

    def start_call(self, name: str, *args: Any) -> None:
        """Send a call without waiting (e.g. a blocking moveL to interrupt)."""
        self._pending = f"{name}{tuple(args)}"
        self.proc.stdin.write((json.dumps({"call": name, "args": list(args)}) + "\n").encode())
        self.proc.stdin.flush()

    def finish_call(self, timeout_s: float = 20.0) -> Any:
        """The result of the call started last."""
        reply = self._read(timeout_s, self._pending)
        if "error" in reply:
            raise RuntimeError(f"{self.kind}.{self._pending}: {reply['error']}")
        return reply["result"]

    def __getattr__(self, name: str):
        if name.startswith("_"):
            raise AttributeError(name)
        return lambda *args, timeout_s=20.0: self.call(name, *args, timeout_s=timeout_s)

    def close(self, timeout_s: float = 20.0) -> int:
        """disconnect(), then let the child exit; its exit code."""
        if self.proc.poll() is None:
            try:
                self.call("disconnect", timeout_s=timeout_s)
            except (RuntimeError, ClientTimeout, BrokenPipeError):
                pass
        return self.wait_exit(timeout_s)

    def wait_exit(self, timeout_s: float) -> int:
        if self.proc.stdin and not self.proc.stdin.closed:
            try:
                self.proc.stdin.close()
            except BrokenPipeError:
                pass
        try:
            return self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.kill()
            raise ClientTimeout(f"{self.kind} client did not exit within {timeout_s} s") from None

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()

    def stderr(self) -> str:
        if self.proc.poll() is None:
            return "(still running)"
        return self.proc.stderr.read().decode(errors="replace")

    def __enter__(self) -> UrClient:
        return self

    def __exit__(self, *exc: object) -> None:
        try:
            self.close()
        finally:
            self.kill()

    def _read(self, timeout_s: float, what: str) -> dict[str, Any]:
        fd = self.proc.stdout.fileno()
        deadline = time.monotonic() + timeout_s
        while b"\n" not in self._buffer:
            remaining = deadline - time.monotonic()
            ready = select.select([fd], [], [], max(0.0, remaining))[0] if remaining > 0 else []
            if not ready:
                self.kill()
                raise ClientTimeout(f"{self.kind} client: no answer to {what} within {timeout_s} s "
                                    f"(killed); stderr:\n{self.stderr()}")
            chunk = os.read(fd, 65536)
            if not chunk:
                code = self.proc.wait()
                raise AssertionError(f"{self.kind} client exited ({code}) during {what}; "
                                     f"stderr:\n{self.stderr()}")
            self._buffer += chunk
        line, _, self._buffer = self._buffer.partition(b"\n")
        return json.loads(line)


def _child(kind: str, host: str, args: list[Any]) -> int:
    # ur_rtde writes to std::cout: keep fd 1 for it (sent on to stderr), answer on a copy
    answers = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)
    module, cls = _MODULES[kind]
    try:
        iface = getattr(__import__(module), cls)(host, *args)
    except Exception as exc:  # noqa: BLE001 - reported to the parent
        answers.write(json.dumps({"error": f"{type(exc).__name__}: {exc}"}) + "\n")
        return 1
    answers.write(json.dumps({"ready": True}) + "\n")
    for line in sys.stdin:
        request = json.loads(line)
        try:
            result = getattr(iface, request["call"])(*request["args"])
            if hasattr(result, "isAsyncOperationRunning"):  # AsyncOperationStatus
                result = {"running": result.isAsyncOperationRunning(), "operation_id": result.operationId(),
                          "progress": result.progress()}
            answers.write(json.dumps({"result": result}) + "\n")
        except Exception as exc:  # noqa: BLE001 - reported to the parent
            answers.write(json.dumps({"error": f"{type(exc).__name__}: {exc}"}) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(_child(sys.argv[1], sys.argv[2], json.loads(sys.argv[3])))
