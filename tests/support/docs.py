"""Running a document's shell blocks as written: the fenced ``sh`` blocks in order, each
line as a shell runs it (``&``: in the background), only announced names replaced."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

from support.harness import REPO


def shell_blocks(doc: Path) -> list[list[str]]:
    """The fenced ``sh`` blocks of a document, in order: their command lines."""
    blocks, current = [], None
    for line in doc.read_text().splitlines():
        if current is None and line.strip() == "```sh":
            current = []
        elif current is not None and line.strip() == "```":
            blocks.append(current)
            current = None
        elif current is not None and line.strip() and not line.lstrip().startswith("#"):
            current.append(line.strip())
    return blocks


def run_as_written(lines: list[str], subs: dict[str, str], tmp_path: Path, timeout_s: float = 600,
                   cwd: Path = REPO, background: list | None = None, prefix: tuple[str, ...] = ()):
    """Each line as a shell runs it from ``cwd`` (``&``: in the background), with only
    ``subs`` replaced; the venv's ``fluidsense`` and ``python`` first on PATH. Returns (the
    background processes with their logs, the foreground results); ``background`` collects
    across calls. ``prefix``: what runs the shell (e.g. nsenter into a network namespace)."""
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}", "PYTHONUNBUFFERED": "1"}
    background = [] if background is None else background
    results = []
    for line in lines:
        for old, new in subs.items():
            line = line.replace(old, new)
        if line.endswith("&") or " & " in line:
            command = line.split(" & ")[0].rstrip("& ").strip()  # the comment after '&' is not the shell's
            log = open(tmp_path / f"bg{len(background)}.log", "w")  # noqa: SIM115 - closed with the process
            # exec: the process is the command itself, which a signal then reaches (not a shell)
            background.append((subprocess.Popen([*prefix, "sh", "-c", "exec " + command], cwd=cwd, env=env,
                                                 stdout=log, stderr=subprocess.STDOUT), log))
        else:
            results.append(subprocess.run([*prefix, "sh", "-c", line], cwd=cwd, env=env, capture_output=True,
                                          text=True, timeout=timeout_s))
    return background, results


def wait_for_ready(proc, log, timeout_s: float = 60.0, marker: str = "ready") -> None:
    """Until the process's log has its ready line, one starting with ``marker`` or, for the
    daemon (``marker="fluidsense running"``), holding it: it exits or the time runs out, the
    test fails."""
    path = Path(log.name)
    deadline = time.monotonic() + timeout_s
    while not any(line.startswith(marker) or (marker != "ready" and marker in line)
                  for line in path.read_text().splitlines()):
        assert proc.poll() is None, path.read_text()
        assert time.monotonic() < deadline, path.read_text()
        time.sleep(0.05)  # polling a file for an event, not pacing a timing


def problems(stdout: str) -> list[str]:
    """What check's result section lists (empty: everything matches)."""
    lines = stdout.split("\nresult\n", 1)[1].splitlines()
    return [line.strip() for line in lines if line.strip() != "everything matches the config"]


def documented_exit(command: str, case_starts: str) -> int:
    """docs/cli.md's per-command exit table: the code of ``command``'s row whose case
    starts with ``case_starts``."""
    text = (REPO / "docs" / "cli.md").read_text()
    rows = re.findall(r"^\| `fluidsense (\w+)[^`]*` \| ([^|]+?) \| (\d+) \|$", text, flags=re.M)
    (code,) = {int(c) for cmd, case, c in rows if cmd == command and case.startswith(case_starts)}
    return code
