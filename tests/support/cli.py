"""The command line run in this process: ``fluidsense.cli.main(argv)`` with pytest's capsys,
for the unit tier's tests of what a command prints and returns (a test about the process
itself, its signals or a real daemon's exit, runs ``python -m fluidsense`` in tests/system/)."""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Ran:
    """What ``python -m fluidsense ...`` would have given: its exit status and output."""

    args: tuple[str, ...]
    returncode: int
    stdout: str
    stderr: str


def run_cli(capsys, *argv: str | os.PathLike, cwd: Path | str | None = None) -> Ran:
    """``fluidsense *argv`` in this process, from ``cwd`` when given. argparse's own exits
    (``--help``: 0, a bad argument: 2) are its exit status, as ``python -m`` would give them."""
    from fluidsense.cli import main

    args = tuple(str(a) for a in argv)
    capsys.readouterr()  # what came before is not this command's
    with contextlib.chdir(cwd) if cwd is not None else contextlib.nullcontext():
        try:
            code = main(list(args))
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    out = capsys.readouterr()
    return Ran(args, code, out.out, out.err)
