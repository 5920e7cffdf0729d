"""The pytest plugin of a ``lab bench suite-cpu`` run (``-p fluidsense_suitecpu_plugin``):
in each worker, one line per test with its wall time, its CPU and the CPU of the children
it reaped, in ``$FLUIDSENSE_SUITECPU_DIR/tests.<worker>.jsonl``; and the run's own pids
(its processes are not the tests') in ``pytest-pids``."""

import json
import os
import resource
import time

import pytest

_OUT = os.environ["FLUIDSENSE_SUITECPU_DIR"]


def _now():
    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.monotonic(), s.ru_utime + s.ru_stime, c.ru_utime + c.ru_stime


def pytest_configure(config):
    with open(os.path.join(_OUT, "pytest-pids"), "a") as f:
        f.write(f"{os.getpid()}\n")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    t0, s0, c0 = _now()
    yield
    t1, s1, c1 = _now()
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    with open(os.path.join(_OUT, f"tests.{worker}.jsonl"), "a") as f:
        f.write(json.dumps({"id": item.nodeid, "wall_s": t1 - t0, "self_s": s1 - s0, "child_s": c1 - c0}) + "\n")
