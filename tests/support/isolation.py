"""The unit tier's boundary: a test there runs in this process only. ``Isolation.install``
(tests/unit/conftest.py, autouse) replaces every way a test could start a process or reach a
peer through the operating system, so that the first such call fails the test, naming it:

- processes: ``subprocess.Popen`` (asyncio's ``create_subprocess_exec``/``_shell`` and
  ``subprocess.run`` go through it), ``os.fork``, ``os.posix_spawn``/``posix_spawnp``,
  ``multiprocessing``'s ``BaseProcess.start``;
- sockets: ``socket.socket.bind``/``connect``/``connect_ex`` for AF_INET, AF_INET6 and AF_UNIX
  (a ``socket.socketpair`` binds nothing, so asyncio's self-pipe is fine), and ZeroMQ's
  ``Socket.bind``/``connect`` for any endpoint but ``inproc://``.

The call raises ``pytest.fail`` at once; it is also recorded, so that a call made on another
thread (whose exception the test never sees) or swallowed by a broad ``except`` still fails
the test at its teardown. A test that needs a real peer belongs in tests/system/."""

from __future__ import annotations

import multiprocessing.process
import os
import socket
import subprocess
import threading
from dataclasses import dataclass, field

import pytest
import zmq

_GUARDED_FAMILIES = {socket.AF_INET: "AF_INET", socket.AF_INET6: "AF_INET6", socket.AF_UNIX: "AF_UNIX"}

HINT = "a unit test runs in this process only: a test that needs a real peer goes in tests/system/"


@dataclass
class Isolation:
    """The calls a test made across the boundary, in order (``violations``)."""

    violations: list[str] = field(default_factory=list)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def refuse(self, what: str, call: str) -> None:
        message = f"the test {what}: {call} ({HINT})"
        with self._lock:
            self.violations.append(message)
        pytest.fail(message, pytrace=True)

    def install(self, monkeypatch: pytest.MonkeyPatch) -> None:
        refuse = self.refuse

        def popen_init(popen, args, *rest, **kwargs):
            refuse("started a process", f"subprocess.Popen({args!r})")

        def fork():
            refuse("started a process", "os.fork()")

        def spawn(name):
            def spawned(path, argv, *rest, **kwargs):
                refuse("started a process", f"os.{name}({path!r}, {list(argv)!r})")
            return spawned

        def process_start(proc):
            refuse("started a process", f"multiprocessing {type(proc).__name__}(name={proc.name!r}).start()")

        monkeypatch.setattr(subprocess.Popen, "__init__", popen_init)
        monkeypatch.setattr(os, "fork", fork)
        for name in ("posix_spawn", "posix_spawnp"):
            if hasattr(os, name):
                monkeypatch.setattr(os, name, spawn(name))
        monkeypatch.setattr(multiprocessing.process.BaseProcess, "start", process_start)

        for name in ("bind", "connect", "connect_ex"):
            original = getattr(socket.socket, name)

            def guarded(sock, address, *rest, _name=name, _original=original):
                family = _GUARDED_FAMILIES.get(sock.family)
                if family is not None:
                    refuse("opened a socket", f"socket.socket({family}).{_name}({address!r})")
                return _original(sock, address, *rest)

            monkeypatch.setattr(socket.socket, name, guarded)

        for name in ("bind", "connect"):
            original = getattr(zmq.Socket, name)

            def zmq_guarded(sock, addr, *rest, _name=name, _original=original, **kwargs):
                if not str(addr).startswith("inproc://"):
                    refuse("opened a socket", f"zmq.Socket.{_name}({addr!r})")
                return _original(sock, addr, *rest, **kwargs)

            monkeypatch.setattr(zmq.Socket, name, zmq_guarded)

    def check(self) -> None:
        """At teardown: a crossing the test did not see (another thread's, or caught) fails it."""
        if self.violations:
            pytest.fail("\n".join(dict.fromkeys(self.violations)), pytrace=False)
