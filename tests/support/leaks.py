"""What a test leaves behind: asyncio tasks still pending when its event loop ended, threads,
child processes and sockets it started and did not end (tests/conftest.py fails the test,
naming each; as ophyd-async's ``fail_test_on_unclosed_tasks`` does for tasks).

Everything is read from the interpreter and from /proc (Linux, where the suite runs): no
process, thread or socket is created to look."""

from __future__ import annotations

import asyncio
import asyncio.runners
import os
import threading
from dataclasses import dataclass, field
from pathlib import Path


#: what the guard lets through, each by name with its reason (a substring of the label)
ALLOWED = {
    # their pools shut down without waiting, so that a hung blocking call cannot hang the
    # close; the idle worker exits moments after, on its own
    "thread 'sim-pacer_": "drivers/sim/backend.py: ThreadPoolExecutor.shutdown(wait=False)",
    "thread 'daqmx-": "drivers/daqmx/calls.py TaskThread.close: ThreadPoolExecutor.shutdown(wait=False)",
    # tqdm starts its monitor thread when a bar is made (tqdm.__new__); a bar made disabled (no
    # terminal: calibrate and characterise run in this process under capsys) never ends it on
    # close, as an enabled one does. It idles, a daemon thread, until the process exits
    "thread 'tqdm_monitor'": "tqdm: a disabled bar's close() does not stop the monitor its __new__ started",
}


#: asyncio's own, as it was before any test's TaskWatch wrapped it: a test that runs pytest
#: inside itself (tests/unit/test_tier_guard.py) hands this to the inner run, whose tasks are
#: the inner run's to judge
ASYNCIO_CANCEL_ALL = asyncio.runners._cancel_all_tasks


def _allowed(label: str) -> bool:
    return any(key in label for key in ALLOWED)


@dataclass(frozen=True)
class Snapshot:
    threads: dict[int, str]  # ident -> name and target
    children: dict[int, str]  # pid -> state and command line
    sockets: dict[str, str]  # "socket:[inode]" -> what it is (address, kind)


def _thread_label(t: threading.Thread) -> str:
    target = getattr(t, "_target", None)
    where = getattr(target, "__qualname__", None) or type(t).__qualname__
    module = getattr(target, "__module__", None) or type(t).__module__
    return f"thread {t.name!r} ({module}.{where}, daemon={t.daemon})"


def _threads() -> dict[int, str]:
    return {t.ident: _thread_label(t) for t in threading.enumerate() if t.ident is not None and t.is_alive()}


def _children() -> dict[int, str]:
    """This process's children, from /proc/<pid>/stat (field 4 is the parent)."""
    me, found = os.getpid(), {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace").strip()
        except OSError:
            continue  # gone while we looked
        # the command name is in parentheses and may hold spaces: the fields after its ')' are fixed
        state, ppid = stat.rsplit(")", 1)[1].split()[:2]
        if int(ppid) == me:
            what = "exited, never waited for" if state == "Z" else "running"
            found[int(entry.name)] = f"child process {entry.name} ({what}): {cmdline or stat.split()[1]}"
    return found


def _socket_names() -> dict[str, str]:
    """inode -> a readable address for the process's TCP, UDP and unix sockets."""
    names: dict[str, str] = {}
    for kind in ("tcp", "tcp6", "udp", "udp6"):
        try:
            lines = Path(f"/proc/self/net/{kind}").read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            f = line.split()
            names[f[9]] = f"{kind} {_addr(f[1])} -> {_addr(f[2])}"
    try:
        for line in Path("/proc/self/net/unix").read_text().splitlines()[1:]:
            f = line.split()
            names[f[6]] = f"unix {f[7] if len(f) > 7 else '(unnamed)'}"
    except OSError:
        pass
    return names


def _addr(hex_addr: str) -> str:
    host, port = hex_addr.split(":")
    if len(host) == 8:  # IPv4, little-endian
        host = ".".join(str(int(host[i:i + 2], 16)) for i in (6, 4, 2, 0))
    else:
        host = "[ipv6]"
    return f"{host}:{int(port, 16)}"


def _sockets() -> dict[str, str]:
    fd_dir = Path("/proc/self/fd")
    found: dict[str, str] = {}
    for fd in fd_dir.iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue  # the listing's own descriptor, closed already
        if target.startswith("socket:["):
            found[target] = target
    if found:
        names = _socket_names()
        for target in found:
            inode = target[len("socket:["):-1]
            found[target] = f"socket {names.get(inode, target)}"
    return found


def snapshot() -> Snapshot:
    return Snapshot(_threads(), _children(), _sockets())


def left_behind(before: Snapshot, after: Snapshot) -> list[str]:
    """What exists now and did not before the test."""
    left = ([label for ident, label in after.threads.items() if ident not in before.threads]
            + [label for pid, label in after.children.items() if pid not in before.children]
            + [label for key, label in after.sockets.items() if key not in before.sockets])
    return [label for label in left if not _allowed(label)]


@dataclass
class TaskWatch:
    """Records the tasks asyncio.run (3.11: ``asyncio.Runner``) finds pending when its main
    coroutine returns: it cancels them silently, so a test whose background task outlived its
    body passes without this."""

    pending: list[str] = field(default_factory=list)

    def install(self, monkeypatch) -> None:
        cancel_all = asyncio.runners._cancel_all_tasks

        def watched(loop: asyncio.AbstractEventLoop) -> None:
            self.pending += [label for t in asyncio.all_tasks(loop) if not t.done()
                             if not _allowed(label := f"asyncio task {t.get_name()!r}: {t.get_coro()!r}")]
            cancel_all(loop)

        monkeypatch.setattr(asyncio.runners, "_cancel_all_tasks", watched)
