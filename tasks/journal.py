"""A calibration's finished cycles, on disk as they complete.

A calibration on a real cell takes many cycles (the paper's protocol: 8 per target, five
to nine targets) and an operator's time. Each finished cycle is appended to a JSON-lines
file beside the calibration (``OUT.cycles.jsonl``) and forced to disk, so a fault, a
Ctrl-C or a power cut loses at most the cycle that was running; ``--resume`` reads it back
and runs only what is missing. The first line is the plan the cycles belong to: a resume
with another plan is refused rather than mixing two calibrations.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from fluidsense.common.errors import ConfigError
from fluidsense.common.files import decode_utf8, read_bounded

MAX_BYTES = 16 * 2**20  # ~100 bytes a cycle: far more cycles than any calibration has
KIND = "fluidsense calibration cycles"


def journal_path(out: str | Path) -> Path:
    return Path(f"{out}.cycles.jsonl")


class CycleJournal:
    def __init__(self, path: Path, plan: dict[str, Any], entries: list[dict[str, Any]]):
        self.path, self.plan, self.entries = path, plan, entries

    @classmethod
    def open(cls, path: str | Path, plan: dict[str, Any], resume: bool) -> CycleJournal:
        """A new journal, or (``resume``) the one at ``path``, checked against ``plan``.
        An existing journal is never overwritten: it holds an operator's work."""
        path = Path(path)
        exists = os.path.lexists(path)
        if resume:
            if not exists:
                raise ConfigError(f"{path}: nothing to resume (no such file)")
            entries, complete = cls._read(path, plan)
            if not complete:  # drop the cycle a crash cut off, so that the next one starts on its own line
                tmp = path.with_name(path.name + ".tmp")
                tmp.write_text("".join(json.dumps(x) + "\n" for x in [{"kind": KIND, "plan": plan}, *entries]),
                               encoding="utf-8")
                os.replace(tmp, path)
        elif exists and CycleJournal._holds_cycles(path):
            raise ConfigError(f"{path}: holds the finished cycles of an earlier run: pass --resume to continue it, "
                              "or move the file away to start again")
        else:  # new, or one that a run left without a single finished cycle
            if exists:
                os.unlink(path)
            entries = []
            with open(path, "x", encoding="utf-8") as f:
                f.write(json.dumps({"kind": KIND, "plan": plan}) + "\n")
                f.flush()
                os.fsync(f.fileno())
        return cls(path, plan, entries)

    @staticmethod
    def _holds_cycles(path: Path) -> bool:
        """Anything beyond the header line (a file that is not a journal counts as holding
        something: it is not ours to delete)."""
        text = decode_utf8(read_bounded(path, MAX_BYTES, "a calibration journal"), path)
        first, _, rest = text.partition("\n")
        try:
            ours = json.loads(first).get("kind") == KIND
        except (json.JSONDecodeError, AttributeError):
            ours = False
        return not ours or bool(rest.strip())

    @staticmethod
    def _read(path: Path, plan: dict[str, Any]) -> tuple[list[dict[str, Any]], bool]:
        """The finished cycles, and whether the file ends cleanly after the last of them."""
        text = decode_utf8(read_bounded(path, MAX_BYTES, "a calibration journal"), path)
        complete = text.endswith("\n")
        lines = text.splitlines()
        try:
            header = json.loads(lines[0]) if lines else None
        except json.JSONDecodeError:
            header = None
        if not isinstance(header, dict) or header.get("kind") != KIND:
            raise ConfigError(f"{path}:1: not a calibration journal")
        if header.get("plan") != plan:
            theirs = header.get("plan") if isinstance(header.get("plan"), dict) else {}
            differ = sorted(k for k in {*plan, *theirs} if plan.get(k) != theirs.get(k))
            raise ConfigError(f"{path}:1: the journal is for another calibration (differs in {', '.join(differ)}): "
                              "give the same profile, scene, target, values, feature, fit and cycles")
        entries = []
        for n, line in enumerate(lines[1:], start=2):
            try:
                e = json.loads(line)
                # value None: a cycle with nothing there (the free reading)
                entry = {"value": None if e["value"] is None else float(e["value"]), "k": int(e["k"]),
                         "cycle_id": int(e["cycle_id"]),
                         "y": None if e["y"] is None else float(e["y"])}
            except (ValueError, KeyError, TypeError) as exc:
                if n == len(lines):  # the cycle a crash cut off while it was written
                    complete = False
                    break
                raise ConfigError(f"{path}:{n}: not a finished cycle ({type(exc).__name__}: {exc})") from exc
            if entry["value"] is None:
                if not 0 <= entry["k"] < plan.get("free_cycles", 0):
                    raise ConfigError(f"{path}:{n}: free cycle {entry['k']} is not in the plan")
            elif entry["value"] not in plan["values"] or not 0 <= entry["k"] < plan["cycles"]:
                raise ConfigError(f"{path}:{n}: cycle {entry['k']} at {entry['value']} is not in the plan")
            entries.append(entry)
        return entries, complete

    def add(self, entry: dict[str, Any]) -> None:
        with open(self.path, "a", encoding="utf-8") as f:
            f.write(json.dumps(entry) + "\n")
            f.flush()
            os.fsync(f.fileno())
        self.entries.append(entry)
