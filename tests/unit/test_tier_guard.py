"""The unit tier's guards, shown on tests written into a scratch folder and run by pytest in
this process (pytester's inline run: no process is started): a unit test that starts a
process, opens a TCP socket, leaves an asyncio task pending or raises a DeprecationWarning
fails, and its report says why. The scratch run has the suite's own settings
(pyproject.toml's [tool.pytest.ini_options]) and conftests (tests/conftest.py and
tests/unit/conftest.py, as they are). One scratch run holds every case: pytester's inline
run imports the suite's conftests afresh each time, about ten seconds here."""

from __future__ import annotations

import asyncio.runners
import re
from pathlib import Path

import pytest
from support import leaks

pytest_plugins = ["pytester"]

TESTS = Path(__file__).resolve().parents[1]
REPO = TESTS.parent


SCRATCH = """
import asyncio
import multiprocessing
import os
import socket
import subprocess
import threading
import warnings

import zmq


def test_runs_true():
    subprocess.run(["true"], check=True)


def test_asyncio_exec():
    async def main():
        await asyncio.create_subprocess_exec("true")
    asyncio.run(main())


def test_fork():
    os.fork()


def test_posix_spawn():
    os.posix_spawn("/bin/true", ["true"], {})


def test_multiprocessing():
    multiprocessing.get_context("spawn").Process(target=print, name="child").start()


def test_listens_on_tcp():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))


def test_connects_over_tcp():
    with socket.socket() as s:
        s.connect(("127.0.0.1", 9))


def test_zmq_tcp_endpoint():
    ctx = zmq.Context()
    s = ctx.socket(zmq.PUB)
    try:
        s.bind("tcp://127.0.0.1:*")
    finally:
        s.close(linger=0)
        ctx.term()


def test_thread_starts_a_process():
    t = threading.Thread(target=lambda: subprocess.run(["true"]))
    t.start()
    t.join()


def test_swallows_the_refusal():
    try:
        subprocess.run(["true"])
    except BaseException:
        pass


async def forever():
    await asyncio.sleep(3600)


def test_leaves_a_task():
    async def main():
        asyncio.get_running_loop().create_task(forever(), name="left-here")
    asyncio.run(main())


def test_warns():
    warnings.warn("this call goes away", DeprecationWarning)


def test_in_process_peers_are_fine():
    ctx = zmq.Context()
    a, b = ctx.socket(zmq.PAIR), ctx.socket(zmq.PAIR)
    a.bind("inproc://tier-guard")
    b.connect("inproc://tier-guard")
    b.send(b"x")
    assert a.recv() == b"x"
    a.close(linger=0)
    b.close(linger=0)
    ctx.term()
    left, right = socket.socketpair()
    left.close()
    right.close()
    assert asyncio.run(asyncio.sleep(0, result=7)) == 7
"""

#: scratch test -> what its failure must say (a regular expression)
EXPECTED = {
    "test_runs_true": r"the test started a process: subprocess\.Popen\(\['true'\]\) \(a unit test runs in "
                      r"this process only: a test that needs a real peer goes in tests/system/\)",
    "test_asyncio_exec": r"started a process: subprocess\.Popen\(\('true',\)\)",
    "test_fork": r"started a process: os\.fork\(\)",
    "test_posix_spawn": r"started a process: os\.posix_spawn\('/bin/true', \['true'\]\)",
    "test_multiprocessing": r"started a process: multiprocessing \w*Process\(name='child'\)\.start\(\)",
    "test_listens_on_tcp": r"opened a socket: socket\.socket\(AF_INET\)\.bind\(\('127\.0\.0\.1', 0\)\)",
    "test_connects_over_tcp": r"opened a socket: socket\.socket\(AF_INET\)\.connect\(\('127\.0\.0\.1', 9\)\)",
    "test_zmq_tcp_endpoint": r"opened a socket: zmq\.Socket\.bind\('tcp://127\.0\.0\.1:\*'\)",
    "test_thread_starts_a_process": r"started a process: subprocess\.Popen\(\['true'\]\)",
    "test_swallows_the_refusal": r"started a process: subprocess\.Popen\(\['true'\]\)",
    "test_leaves_a_task": r"the test left behind:\s+asyncio task 'left-here'.*forever",
    "test_warns": r"DeprecationWarning: this call goes away",
}


def test_each_crossing_of_the_unit_tier_fails_its_test_naming_why(pytester: pytest.Pytester, monkeypatch):
    # the scratch run's tasks are its own guard's to judge, not this test's
    monkeypatch.setattr(asyncio.runners, "_cancel_all_tasks", leaks.ASYNCIO_CANCEL_ALL)
    ini = REPO.joinpath("pyproject.toml").read_text()
    pytester.makepyprojecttoml(ini[ini.index("[tool.pytest.ini_options]"):ini.index("[tool.importlinter]")])
    unit = TESTS.joinpath("unit", "conftest.py").read_text().replace("from __future__ import annotations\n", "")
    pytester.makeconftest(TESTS.joinpath("conftest.py").read_text() + "\n\n" + unit)
    pytester.makepyfile(test_scratch=SCRATCH)
    recorded = pytester.inline_run("test_scratch.py", "-p", "no:cacheprovider", "-n", "0")
    reports: dict[str, list] = {}
    for report in recorded.getreports("pytest_runtest_logreport"):
        reports.setdefault(report.nodeid.split("::")[-1], []).append(report)
    assert set(reports) == set(EXPECTED) | {"test_in_process_peers_are_fine"}, sorted(reports)
    for name, expected in EXPECTED.items():
        failed = [r for r in reports[name] if r.failed]
        said = "\n".join(str(r.longrepr) for r in failed)
        assert failed, f"{name} passed: the guard let it through"
        assert re.search(expected, said, re.S), (name, expected, said[-3000:])
    assert all(r.passed for r in reports["test_in_process_peers_are_fine"]), reports["test_in_process_peers_are_fine"]
