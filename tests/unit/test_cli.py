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


def test_the_benches_listing_names_every_bench(capsys):
    """`python -m lab bench --help`: argparse %-formats each help line, and a bench's own
    "95 % error" once ended the listing in a ValueError."""
    from lab.__main__ import main
    from lab.bench import discover

    with pytest.raises(SystemExit) as done:
        main(["bench", "--help"])
    assert done.value.code == 0
    listing = capsys.readouterr().out
    assert all(name in listing for name in discover())
    assert "95 % |error|" in listing
