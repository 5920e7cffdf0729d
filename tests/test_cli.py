"""The command line: every command documents itself."""

from __future__ import annotations

import subprocess
import sys

import pytest

from .conftest import REPO


@pytest.mark.parametrize("command, expected", [
    ([], ["run", "demo", "monitor", "cmd"]),
    (["run"], ["--config", "--virtual", "SIGTERM"]),
    (["demo"], ["--json", "--seed", "4-5 s"]),
    (["monitor"], ["--endpoint", "--count", "--timeout"]),
    (["cmd"], ["status", "--endpoint"]),
])
def test_help(command, expected):
    out = subprocess.run([sys.executable, "-m", "fluidsense.cli", *command, "--help"], cwd=REPO,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0
    for word in expected:
        assert word in out.stdout


def test_cmd_without_a_daemon_times_out_with_a_clear_error(tmp_path):
    out = subprocess.run([sys.executable, "-m", "fluidsense.cli", "cmd", "status", "--endpoint",
                          f"ipc://{tmp_path}/nobody", "--timeout", "0.2"], cwd=REPO,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 3
    assert "no reply" in out.stderr
