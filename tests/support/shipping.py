"""Reading what ships: the Dockerfile's instructions, the systemd unit's entries and the
shell blocks of docs/deployment.md (tests/accept/test_ship.py, tests/system/test_deploy.py)."""

from __future__ import annotations

import re
from pathlib import Path

from support.harness import REPO

UNIT = REPO / "config" / "systemd" / "fluidsense.service"
DEPLOYMENT = REPO / "docs" / "deployment.md"


def dockerfile() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments), continuation lines joined."""
    text = re.sub(r"\\\n", " ", (REPO / "Dockerfile").read_text())
    return [(line.split(None, 1)[0].upper(), line.split(None, 1)[1].strip())
            for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]


def stages(steps: list[tuple[str, str]]) -> dict[str, list[tuple[str, str]]]:
    """Stage name (the last one: "final") -> its steps, FROM included."""
    starts = [i for i, (k, _) in enumerate(steps) if k == "FROM"] + [len(steps)]
    out = {}
    for i, j in zip(starts, starts[1:]):
        out["final" if j == len(steps) else steps[i][1].split()[-1]] = steps[i:j]
    return out


def unit_entries(path: Path = UNIT) -> dict[str, list[str]]:
    """``Section.Key`` -> values (systemd allows a key several times)."""
    out: dict[str, list[str]] = {}
    section = None
    for raw in path.read_text().splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("["):
            section = line.strip("[]")
            continue
        key, _, value = line.partition("=")
        out.setdefault(f"{section}.{key.strip()}", []).append(value.strip())
    return out


def doc_block(marker: str, path: Path = DEPLOYMENT) -> str:
    """The first ```sh block after ``marker`` (a heading, the start of a paragraph),
    continuation lines joined."""
    text = path.read_text()
    block = re.search(r"```sh\n(.*?)```", text[text.index(marker):], re.S)
    assert block, f"no sh block after {marker!r} in {path.name}"
    return block.group(1).replace("\\\n", " ")
