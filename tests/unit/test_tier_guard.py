"""The unit tier's guards, shown on tests written into a scratch folder and run by pytest in
this process (pytester's inline run: no process is started): a unit test that starts a
process, opens a TCP socket, leaves an asyncio task pending or raises a DeprecationWarning
fails, and its report says why. The scratch run has the suite's own settings
(pyproject.toml's [tool.pytest.ini_options]) and conftests (tests/conftest.py and
tests/unit/conftest.py, as they are)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

pytest_plugins = ["pytester"]

TESTS = Path(__file__).resolve().parents[1]
REPO = TESTS.parent


@pytest.fixture
def unit_tier(pytester: pytest.Pytester):
    """A scratch suite configured as tests/unit is; returns a function that runs one test
    file there and gives its outcome counts and report text."""
    ini = REPO.joinpath("pyproject.toml").read_text()
    pytester.makepyprojecttoml(ini[ini.index("[tool.pytest.ini_options]"):ini.index("[tool.importlinter]")])
    pytester.makeconftest(TESTS.joinpath("conftest.py").read_text() + "\n\n"
                          + TESTS.joinpath("unit", "conftest.py").read_text())

    def run(source: str):
        pytester.makepyfile(test_scratch=source)
        result = pytester.runpytest_inprocess("-p", "no:cacheprovider", "-n", "0")
        return result.parseoutcomes(), result.stdout.str()

    return run


def _failed_with(outcomes: dict, text: str, *expected: str) -> None:
    assert outcomes.get("failed", 0) + outcomes.get("errors", 0) >= 1 and not outcomes.get("passed"), (outcomes, text)
    for what in expected:
        assert re.search(what, text), (what, text)


def test_a_unit_test_that_starts_a_process_fails_naming_the_call(unit_tier):
    outcomes, text = unit_tier("""
import subprocess

def test_runs_true():
    subprocess.run(["true"], check=True)
""")
    _failed_with(outcomes, text, r"started a process: subprocess\.Popen\(\['true'\]\)", "tests/system/")


def test_asyncio_subprocesses_forks_and_multiprocessing_fail_too(unit_tier):
    outcomes, text = unit_tier("""
import asyncio
import multiprocessing
import os

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
""")
    assert outcomes.get("failed") == 4 and not outcomes.get("passed"), (outcomes, text)
    for call in (r"subprocess\.Popen\(\('true',\)\)", r"os\.fork\(\)", r"os\.posix_spawn\('/bin/true', \['true'\]\)",
                 r"multiprocessing \w*Process\(name='child'\)\.start\(\)"):
        assert re.search("started a process: " + call, text), (call, text)


def test_a_unit_test_that_opens_a_tcp_socket_fails_naming_the_address(unit_tier):
    outcomes, text = unit_tier("""
import socket

def test_listens():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
""")
    _failed_with(outcomes, text, r"opened a socket: socket\.socket\(AF_INET\)\.bind\(\('127\.0\.0\.1', 0\)\)")


def test_zeromq_outside_inproc_fails_and_inproc_and_socketpairs_pass(unit_tier):
    outcomes, text = unit_tier("""
import asyncio
import socket
import zmq

def test_tcp_endpoint():
    ctx = zmq.Context()
    s = ctx.socket(zmq.PUB)
    try:
        s.bind("tcp://127.0.0.1:*")
    finally:
        s.close(linger=0)
        ctx.term()

def test_inproc_endpoint_and_socketpair_and_an_event_loop():
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
""")
    assert outcomes.get("failed") == 1 and outcomes.get("passed") == 1, (outcomes, text)
    assert re.search(r"opened a socket: zmq\.Socket\.bind\('tcp://127\.0\.0\.1:\*'\)", text), text


def test_a_crossing_on_another_thread_fails_the_test_at_its_end(unit_tier):
    outcomes, text = unit_tier("""
import subprocess
import threading

def test_thread_starts_a_process():
    t = threading.Thread(target=lambda: subprocess.run(["true"]))
    t.start()
    t.join()
""")
    _failed_with(outcomes, text, r"started a process: subprocess\.Popen\(\['true'\]\)")


def test_a_unit_test_that_leaves_a_task_pending_fails_naming_it(unit_tier):
    outcomes, text = unit_tier("""
import asyncio

async def forever():
    await asyncio.sleep(3600)

def test_leaves_a_task():
    async def main():
        asyncio.get_running_loop().create_task(forever(), name="left-here")
    asyncio.run(main())
""")
    _failed_with(outcomes, text, r"the test left behind:", r"asyncio task 'left-here'.*forever")


def test_a_unit_test_that_raises_a_deprecation_warning_fails_naming_it(unit_tier):
    outcomes, text = unit_tier("""
import warnings

def test_warns():
    warnings.warn("this call goes away", DeprecationWarning)
""")
    _failed_with(outcomes, text, r"DeprecationWarning: this call goes away")
