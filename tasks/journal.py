"""A calibration's finished cycles, on disk as they complete.

A calibration on a real cell takes many cycles (the paper's protocol: 8 per target, five
to nine targets) and an operator's time. Each finished cycle is appended to a JSON-lines
file beside the calibration (``OUT.cycles.jsonl``) and forced to disk, so a fault, a
Ctrl-C or a power cut loses at most the cycle that was running; ``--resume`` reads it back
and runs only what is missing. The first line is the plan the cycles belong to: a resume
with another plan is refused rather than mixing two calibrations.

Every cycle's line carries a checksum chained to the line before it (the first to the
header): a line edited by hand, moved, or pasted from another journal breaks the chain and
the resume is refused at that line, rather than fitting a curve through a number nobody
measured. The checksum is against mistakes, not an adversary (it is not keyed).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

from fluidsense.common.errors import ConfigError
from fluidsense.common.files import decode_utf8, read_bounded

MAX_BYTES = 16 * 2**20  # ~100 bytes a cycle: far more cycles than any calibration has
KIND = "fluidsense calibration cycles"
VERSION = 2  # 2: each cycle's line has a chained checksum


def _canonical(obj: Any) -> bytes:
    return json.dumps(obj, sort_keys=True, separators=(",", ":")).encode()


def _chain(previous: str, obj: dict[str, Any]) -> str:
    return hashlib.sha256(previous.encode() + _canonical(obj)).hexdigest()[:16]


def _header(plan: dict[str, Any], kind: str = KIND) -> dict[str, Any]:
    return {"kind": kind, "version": VERSION, "plan": plan}


def journal_path(out: str | Path) -> Path:
    return Path(f"{out}.cycles.jsonl")


class CycleJournal:
    """A calibration's cycles. A job with cycles of another shape (characterise) subclasses
    it with its own ``KIND``, ``WHAT``, ``parse_entry`` and ``check_entry``."""

    KIND = KIND
    WHAT = "a calibration journal"

    def __init__(self, path: Path, plan: dict[str, Any], entries: list[dict[str, Any]]):
        self.path, self.plan, self.entries = path, plan, entries
        self._sum = _chain("", _header(plan, self.KIND))
        for entry in entries:
            self._sum = _chain(self._sum, entry)

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
                tmp.write_text("".join(json.dumps(x) + "\n" for x in [_header(plan, cls.KIND),
                                                                     *_summed(plan, entries, cls.KIND)]),
                               encoding="utf-8")
                os.replace(tmp, path)
        elif exists and cls._holds_cycles(path):
            raise ConfigError(f"{path}: holds the finished cycles of an earlier run: pass --resume to continue it, "
                              "or move the file away to start again")
        else:  # new, or one that a run left without a single finished cycle
            if exists:
                os.unlink(path)
            entries = []
            with open(path, "x", encoding="utf-8") as f:
                f.write(json.dumps(_header(plan, cls.KIND)) + "\n")
                f.flush()
                os.fsync(f.fileno())
        return cls(path, plan, entries)

    @classmethod
    def _holds_cycles(cls, path: Path) -> bool:
        """Anything beyond the header line (a file that is not a journal counts as holding
        something: it is not ours to delete)."""
        text = decode_utf8(read_bounded(path, MAX_BYTES, cls.WHAT), path)
        first, _, rest = text.partition("\n")
        try:
            ours = json.loads(first).get("kind") == cls.KIND
        except (json.JSONDecodeError, AttributeError):
            ours = False
        return not ours or bool(rest.strip())

    @staticmethod
    def parse_entry(e: dict[str, Any]) -> dict[str, Any]:
        """One cycle's line as the job wrote it (KeyError, ValueError, TypeError when it is
        not one)."""
        # value None: a cycle with nothing there (the free reading)
        return {"value": None if e["value"] is None else float(e["value"]), "k": int(e["k"]),
                "cycle_id": int(e["cycle_id"]), "y": None if e["y"] is None else float(e["y"])}

    @staticmethod
    def check_entry(entry: dict[str, Any], plan: dict[str, Any]) -> str | None:
        """Why a cycle does not belong to the plan (None: it does)."""
        if entry["value"] is None:
            if not 0 <= entry["k"] < plan.get("free_cycles", 0):
                return f"free cycle {entry['k']} is not in the plan"
        elif entry["value"] not in plan["values"] or not 0 <= entry["k"] < plan["cycles"]:
            return f"cycle {entry['k']} at {entry['value']} is not in the plan"
        return None

    @classmethod
    def _read(cls, path: Path, plan: dict[str, Any]) -> tuple[list[dict[str, Any]], bool]:
        """The finished cycles, and whether the file ends cleanly after the last of them."""
        text = decode_utf8(read_bounded(path, MAX_BYTES, cls.WHAT), path)
        complete = text.endswith("\n")
        lines = text.splitlines()
        try:
            header = json.loads(lines[0]) if lines else None
        except json.JSONDecodeError:
            header = None
        if not isinstance(header, dict) or header.get("kind") != cls.KIND:
            raise ConfigError(f"{path}:1: not {cls.WHAT}")
        if header.get("version") != VERSION:
            raise ConfigError(f"{path}:1: a journal of another fluidsense version (lines without checksums): its "
                              "cycles cannot be checked; move the file away to start again")
        if header.get("plan") != plan:
            theirs = header.get("plan") if isinstance(header.get("plan"), dict) else {}
            differ = sorted(k for k in {*plan, *theirs} if plan.get(k) != theirs.get(k))
            raise ConfigError(f"{path}:1: the journal is for another run (differs in {', '.join(differ)}): "
                              "give the same plan (profile, scene, target, values, levels, cycles, ...) as the run "
                              "it resumes")
        entries: list[dict[str, Any]] = []
        last = _chain("", header)
        for n, line in enumerate(lines[1:], start=2):
            try:
                e = json.loads(line)
                entry = cls.parse_entry(e)
                if e.get("sum") != _chain(last, entry):
                    raise ValueError("its checksum does not follow the line before")
            except (ValueError, KeyError, TypeError, AttributeError) as exc:
                if n == len(lines) and not complete:  # the cycle a crash cut off while it was written
                    break
                raise ConfigError(f"{path}:{n}: not a finished cycle of this journal ({exc}: edited, moved or copied "
                                  f"from another journal); move the file away to start again, or delete line {n} and "
                                  "those after it to resume before it") from exc
            last = e["sum"]
            wrong = cls.check_entry(entry, plan)
            if wrong is not None:
                raise ConfigError(f"{path}:{n}: {wrong}")
            entries.append(entry)
        return entries, complete

    def add(self, entry: dict[str, Any]) -> None:
        self._sum = _chain(self._sum, entry)
        with open(self.path, "a", encoding="utf-8") as f:
            f.write(json.dumps({**entry, "sum": self._sum}) + "\n")
            f.flush()
            os.fsync(f.fileno())
        self.entries.append(entry)


def _summed(plan: dict[str, Any], entries: list[dict[str, Any]], kind: str = KIND) -> list[dict[str, Any]]:
    """The entries as their lines are written: each with its checksum."""
    out, last = [], _chain("", _header(plan, kind))
    for entry in entries:
        last = _chain(last, entry)
        out.append({**entry, "sum": last})
    return out
