"""Fixtures, collection order and each tier's timeout for the three tiers (unit/, system/,
accept/: tests/README.md); the helpers themselves are in support/."""

from __future__ import annotations

import asyncio
import gc
import os
import signal
from pathlib import Path

import pytest
from fluidsense.common.errors import LinkLostError
from fluidsense.simulator.controlbox.process import EmulatorProcess
from support import leaks
from support.controlbox import MODBUS_PORT, free_host
from support.harness import REPO, Daemon, sim_config

# The system tier's files that take longest, longest first: seconds of each file's tests
# (setup + call + teardown of those over 3 s, summed) in `pytest tests/system -n 2 --dist
# loadfile` on 2026-11-28, on the 2-core machine shared with other work at load 5 (20 min 42 s
# in all): test_box_lies 307 (nine boxes and daemons started in turn), test_scenes 208,
# test_characterise 202, test_gripper_box 181, test_check 163, test_calibration 144 (its
# tank-method study), test_speed_stability 138, test_drivers 61+, ...; every other file under
# 40 s. `make test` hands whole files to the workers in collection order (--dist loadfile
# --no-loadscope-reorder), so these go first and the short ones fill in at the end (the unit
# tier's, seconds each, last of all), rather than one long file starting last. Before this
# list, a long file that was not in it started near the end: 18 min 03 s for the suite where
# 13 min was usual. (The order, not the measured seconds, is what matters.) Keyed by tier:
# a unit file of the same name is not the long one.
LONGEST_FIRST = [
    "system/test_characterise.py", "system/test_gripper_box.py", "system/test_characterise_contact.py",
    "system/test_characterise_iso.py", "system/test_box_lies.py", "system/test_characterise_flow.py", "system/test_scenes.py",
    "system/test_check.py", "system/test_calibration.py", "system/test_speed_stability.py", "system/test_drivers.py",
    "system/test_serial.py", "system/test_report.py", "system/test_accuracy.py", "system/test_tasks.py",
    "system/test_recording.py", "system/test_zmq.py", "system/test_controlbox.py", "system/test_soak.py",
    "system/test_backends.py", "system/test_security.py", "system/test_box_watchdog.py", "system/test_serial_lies.py",
    "system/test_stop_signals.py", "system/test_controller.py", "system/test_examples.py", "system/test_protocol.py",
    "system/test_jobs.py", "system/test_cli.py", "system/test_chart.py",
    # the acceptance tier, by itself in `make accept`: the README's walk is the longest by far
    "accept/test_readme.py", "accept/test_bringup_doc.py", "accept/test_ship.py", "accept/test_examples.py",
]


def _tier_path(item) -> str:
    return f"{item.path.parent.name}/{item.path.name}"


#: each tier's per-test timeout (pytest-timeout), for a test that names none of its own. The
#: unit tier runs in this process on the simulated cell's virtual time: a minute is far past
#: any test of it, and a hang there costs a minute, not five. The system tier waits on real
#: peers in real time (daemons, boxes, boards), slower on a loaded machine: five minutes. The
#: acceptance tier walks the documents as written, in real time, each walk minutes long on a
#: quiet machine and several times that beside other work (the README's walk: about 378 s
#: quiet, issue 35): each of its files names its own (tests/accept/), and this is the bound
#: for one that does not.
TIER_TIMEOUT_S = {"unit": 60, "system": 300, "accept": 1800}


#: how a tier's timeout stops a test. pytest-timeout's default (SIGALRM, raising in the main
#: thread) can land inside an asyncio callback or a background task, which swallows it, and
#: the test then waits for ever (seen: a unit test past its minute on a loaded machine, still
#: waiting ten minutes later). The unit tier starts no process, so its worker may be ended
#: outright ("thread": the stacks are printed, then the worker exits and the test fails as
#: crashed); the system tier's workers have daemons and boxes to stop, so they keep SIGALRM.
TIER_TIMEOUT_METHOD = {"unit": "thread"}


def _tier_timeouts(items) -> None:
    for item in items:
        tier = item.path.parent.name
        if tier in TIER_TIMEOUT_S and item.get_closest_marker("timeout") is None:
            method = TIER_TIMEOUT_METHOD.get(tier)
            item.add_marker(pytest.mark.timeout(TIER_TIMEOUT_S[tier], **({"method": method} if method else {})))


def _longest_first(items) -> None:
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(_tier_path(item), len(rank)))  # stable: the rest keep their order


def pytest_collection_modifyitems(config, items):
    """Longest files first and each tier's timeout (above). ``hardware`` tests need a real robot cell: they run
    only when selected with ``-m hardware`` (and FLUIDSENSE_HARDWARE_CONFIG names its
    cell config)."""
    _longest_first(items)
    _tier_timeouts(items)
    if "hardware" in (config.getoption("-m") or ""):
        return
    skip = pytest.mark.skip(reason="needs a real robot cell: run with -m hardware")
    for item in items:
        if "hardware" in item.keywords:
            item.add_marker(skip)


def pytest_collection_finish(session):
    """What is alive once the tests are collected (the libraries, the test modules) is kept out
    of the collector's walks from here on (gc.freeze): the full collection that the leak guard
    below runs at every test's end then walks only what the tests made since. Walking
    everything each time cost about 0.1 s a test, the most of a unit tier of 1200 tests."""
    gc.collect()
    gc.freeze()


@pytest.hookimpl(wrapper=True, tryfirst=True)
def pytest_runtest_makereport(item, call):
    """Each phase's report on its item: the leak guard below judges only a test that passed."""
    report = yield
    setattr(item, f"_report_{report.when}", report)
    return report


@pytest.fixture(autouse=True)
def nothing_left_behind(request, monkeypatch):
    """Fails a test that leaves behind what it started: asyncio tasks still pending when its
    event loop ended (asyncio.run cancels them without a word), threads, child processes or
    sockets, each named. Only a test that passed is judged (a failed one stops half-way, and
    its own failure says why). Children left running are killed here, so that one test's
    daemons do not load the next ones. What a module- or session-scoped fixture starts exists
    before this snapshot and is not counted."""
    tasks = leaks.TaskWatch()
    tasks.install(monkeypatch)
    before = leaks.snapshot()
    yield
    # what the test dropped is collected now, so a ResourceWarning (an unclosed file or socket,
    # an error under filterwarnings) is reported at this test, not at whichever test the
    # collector happens to run in
    gc.collect()
    after = leaks.snapshot()
    left = tasks.pending + leaks.left_behind(before, after)
    for pid in set(after.children) - set(before.children):
        try:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        except (ProcessLookupError, ChildProcessError):
            pass  # ended, or reaped by its Popen meanwhile
    call = getattr(request.node, "_report_call", None)
    if left and call is not None and call.passed:
        pytest.fail("the test left behind:\n  " + "\n  ".join(left), pytrace=False)


@pytest.fixture
def daemon_factory():
    made: list[Daemon] = []

    def make(config: Path, *extra: str, env: dict[str, str] | None = None) -> Daemon:
        d = Daemon(config, *extra, env=env)
        made.append(d)
        return d

    yield make
    for d in made:
        d.close()


@pytest.fixture
def virtual_controller(tmp_path):
    """Run ``body(controller)`` on a started virtual-time controller; returns its result."""
    from fluidsense.controller.config import load_cell_config
    from fluidsense.daemon import app

    def go(body, **kwargs):
        cfg = load_cell_config(sim_config(tmp_path, **kwargs))

        async def main():
            async with app.controller(cfg) as ctrl:
                return await body(ctrl)

        return asyncio.run(main())

    return go


@pytest.fixture
def start_box():
    started: list[EmulatorProcess] = []

    def start(*args: str, model: str | None = None) -> EmulatorProcess:
        for _ in range(5):
            # the box's child imports a test model (tests.support.controlbox_models) from the checkout
            box = EmulatorProcess(free_host(), modbus_port=MODBUS_PORT, model=model, args=args, cwd=REPO)
            try:
                box.start(timeout_s=30)
            except LinkLostError:
                if "cannot listen" in box.log():  # lost a race for the address: next one
                    continue
                raise
            started.append(box)
            return box
        raise RuntimeError("could not start the emulator on a free address")

    yield start
    for box in started:
        killed = box.proc.poll() is not None and box.proc.returncode == -signal.SIGKILL
        code = box.stop()
        box.__exit__(None, None, None)
        # every box ends cleanly: exit 0 on SIGTERM, nothing crashed on the way
        assert killed or code == 0, box.log()
        assert "Traceback" not in box.log(), box.log()
