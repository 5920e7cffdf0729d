"""The unit tier: in this process only. The guard below fails a test (or a fixture of its
module) that starts a process or opens a socket other than ZeroMQ's ``inproc://``, naming
the call (support/isolation.py says which calls). A test that needs a real peer goes in
tests/system/; one that walks a document as written, in tests/accept/."""

from __future__ import annotations

import pytest
from support.isolation import Isolation


@pytest.fixture(scope="package", autouse=True)
def _in_process_only_here():
    """Installed once for the tier (so module-scoped fixtures are guarded too), and removed
    when a run moves on to another tier's files."""
    isolation = Isolation()
    with pytest.MonkeyPatch.context() as patch:
        isolation.install(patch)
        yield isolation


@pytest.fixture(autouse=True)
def in_process_only(request, _in_process_only_here):
    """Each test's crossings, judged at its end: one made on another thread, or swallowed by
    the code under test, fails a test that passed all the same (one that failed has said so)."""
    _in_process_only_here.violations.clear()
    yield
    call = getattr(request.node, "_report_call", None)
    if call is None or call.passed:
        _in_process_only_here.check()
