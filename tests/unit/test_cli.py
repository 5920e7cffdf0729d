"""The command line: every command documents itself (``fluidsense.cli.main`` in this
process; the command line as a process is tests/system/test_cli.py)."""

from __future__ import annotations

import pytest
from support.cli import run_cli


@pytest.mark.parametrize("command, expected", [
    ([], ["run", "demo", "monitor", "cmd"]),
    (["run"], ["--config", "--virtual", "SIGTERM"]),
    (["demo"], ["--json", "--seed", "4-5 s"]),
    (["monitor"], ["--endpoint", "--count", "--timeout"]),
    (["cmd"], ["status", "cycle", "abort", "reset", "scene", "task", "shutdown", "--endpoint"]),
])
def test_help(command, expected, capsys):
    out = run_cli(capsys, *command, "--help")
    assert out.returncode == 0, out.stderr
    for word in expected:
        assert word in out.stdout
