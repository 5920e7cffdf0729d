"""Free-air references kept on disk, so that a restarted daemon (a crash, kill -9, an
update) can still tell an object from none without someone emptying the gripper again.

A reference is only worth what it was measured on: the same profile's sequence (timing,
windows; P0 is each reference's own key), circuit, actuator and sensors, through the same
driver at the same rate and sensor wiring. Each one is kept with a hash of each of those
parts (``identity``), its P0 and when it was measured. At start the daemon takes back
the ones whose every part matches and refuses the others, saying which part changed.

The file (``references.file``, by default ``references.json`` in ``recording.dir``: the
daemon's state beside its recordings) is replaced whole on each new reference: written
to a temporary file beside it, forced to disk, renamed over the old one, so a crash
leaves the old file or the new one, never half of one. It is read as untrusted input:
size-capped, every field checked; a bad file is refused with the reason, never fatal.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from fluidsense.common.errors import ConfigError
from fluidsense.common.files import decode_utf8, read_bounded
from fluidsense.common.units import KPA

from ..config import CellConfig
from .analysis import Reference, reference_key

log = logging.getLogger(__name__)

KIND = "fluidsense free-air references"
VERSION = 1
#: a 20 s trace at 1 kHz is ~0.8 MB of JSON; a few P0s of the longest profiles fit
MAX_BYTES = 64 * 2**20

#: what a reference belongs to, part by part (the refusal names the part that changed)
PARTS = ("profile", "sequence", "circuit", "actuator", "sensor", "driver")


def _digest(obj: Any) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, separators=(",", ":")).encode()).hexdigest()[:16]


def identity(cfg: CellConfig) -> dict[str, str]:
    """The cell a reference belongs to: the profile's name, and a hash of each part that
    shapes a free-air trace. P0 is left out of the sequence: it is each reference's key."""
    prof = cfg.profile
    driver = cfg.driver.model_dump(mode="json")
    wiring = driver.get("wiring") or {}
    return {
        "profile": prof.name,
        "sequence": _digest(prof.sequence.model_dump(mode="json", exclude={"p0_kpa"})),
        "circuit": _digest(prof.circuit.model_dump(mode="json")),
        "actuator": _digest(prof.actuator.model_dump(mode="json")),
        "sensor": _digest(prof.sensor.model_dump(mode="json")),
        # the samples' rate and the sensors' transfer shape the trace; a sim's seed or a host do not
        "driver": _digest({"kind": driver.get("kind"), "rate_hz": driver.get("rate_hz"),
                           "sensors": wiring.get("sensors")}),
    }


def default_path(cfg: CellConfig) -> Path | None:
    if not cfg.references.keep:
        return None
    return Path(cfg.references.file) if cfg.references.file is not None else Path(cfg.recording.dir) / "references.json"


@dataclass
class Kept:
    """One reference as the daemon holds it: from this run or taken back from disk."""

    p0_kpa: float
    reference: Reference
    measured_unix_s: float
    source: str  # "measured" (this run) or "kept" (read back at start)


class ReferenceKeeper:
    """The references on disk of one daemon. ``path`` None: nothing is kept (a library
    caller, ``references.keep: false``); ages are still reported."""

    def __init__(self, path: Path | None, ident: dict[str, str]):
        self.path, self.ident = path, ident
        self.kept: dict[float, Kept] = {}
        self.refused: list[dict[str, Any]] = []
        self.error: str | None = None  # the last write that failed, or a file that could not be read

    # ------------------------------------------------------------------ reading back
    def load(self) -> dict[float, Kept]:
        """The references on disk that belong to this cell; the others refused, each with
        a log line saying why."""
        if self.path is None or not os.path.lexists(self.path):
            return {}
        try:
            data = json.loads(decode_utf8(read_bounded(self.path, MAX_BYTES, "a references file"), self.path))
            entries = self._entries(data)
        except (ConfigError, ValueError, RecursionError) as exc:  # JSON nested too deep: RecursionError
            self.error = f"{self.path}: not read: {exc}"
            log.warning("kept free-air references refused: %s", self.error)
            return {}
        out: dict[float, Kept] = {}
        for i, entry in enumerate(entries):
            try:
                kept = self._entry(entry)
            except ValueError as exc:
                self.refused.append({"p0_kpa": None, "reason": f"entry {i}: {exc}"})
                log.warning("%s: kept free-air reference %d refused: %s", self.path, i, exc)
                continue
            changed = [part for part in PARTS if entry["identity"].get(part) != self.ident[part]]
            if changed:
                reason = self._why(entry["identity"], changed)
                self.refused.append({"p0_kpa": kept.p0_kpa, "reason": reason})
                log.warning("kept free-air reference at %g kPa (cycle %d) refused: %s", kept.p0_kpa,
                            kept.reference.cycle_id, reason)
                continue
            out[reference_key(kept.p0_kpa * KPA)] = kept
            log.info("kept free-air reference at %g kPa taken back from %s (cycle %d, %.0f s old)", kept.p0_kpa,
                     self.path, kept.reference.cycle_id, time.time() - kept.measured_unix_s)
        self.kept = dict(out)
        return out

    def _why(self, theirs: dict[str, str], changed: list[str]) -> str:
        if "profile" in changed:
            return (f"measured with profile {theirs.get('profile')!r}, this daemon runs {self.ident['profile']!r}; "
                    "take a new one")
        what = ", ".join("driver (kind, rate or sensor wiring)" if p == "driver" else f"the profile's {p}"
                         for p in changed)
        return f"{what} changed since it was measured; take a new one"

    @staticmethod
    def _entries(data: Any) -> list[Any]:
        if not isinstance(data, dict) or data.get("kind") != KIND:
            raise ValueError(f"not a file of {KIND}")
        if data.get("version") != VERSION:
            raise ValueError(f"version {data.get('version')!r}, this daemon reads {VERSION}")
        entries = data.get("references")
        if not isinstance(entries, list):
            raise ValueError("references: not a list")
        return entries

    @staticmethod
    def _entry(entry: Any) -> Kept:
        if not isinstance(entry, dict):
            raise ValueError("not an object")
        ident, p0, at, cycle = (entry.get(k) for k in ("identity", "p0_kpa", "measured_unix_s", "cycle_id"))
        if not isinstance(ident, dict) or not all(isinstance(ident.get(p), str) for p in PARTS):
            raise ValueError("identity: missing or incomplete")
        for name, v in (("p0_kpa", p0), ("measured_unix_s", at)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"{name}: not a finite number")
        if isinstance(cycle, bool) or not isinstance(cycle, int):
            raise ValueError("cycle_id: not an integer")
        arrays = []
        for name in ("t_rel_s", "p_pa"):
            v = entry.get(name)
            if not isinstance(v, list) or len(v) < 2 or \
                    not all(not isinstance(x, bool) and isinstance(x, (int, float)) for x in v):
                raise ValueError(f"{name}: not a list of numbers")
            a = np.asarray(v, dtype=float)
            if not np.all(np.isfinite(a)):
                raise ValueError(f"{name}: not finite")
            arrays.append(a)
        t, p = arrays
        if len(t) != len(p) or np.any(np.diff(t) <= 0):
            raise ValueError("t_rel_s and p_pa: of different lengths, or times not increasing")
        return Kept(float(p0), Reference(t, p, cycle), float(at), "kept")

    # ------------------------------------------------------------------ keeping
    def add(self, p0_pa: float, key: float, reference: Reference) -> dict[str, Any] | None:
        """A reference measured now: held, and (with a path) the whole set to write, which
        ``write`` does off the sample loop. Returns what to write, or None."""
        self.kept[key] = Kept(p0_pa / KPA, reference, time.time(), "measured")
        return self.snapshot() if self.path is not None else None

    def snapshot(self) -> dict[str, Any]:
        return {"kind": KIND, "version": VERSION, "references": [
            {"p0_kpa": k.p0_kpa, "cycle_id": k.reference.cycle_id, "measured_unix_s": k.measured_unix_s,
             "identity": self.ident, "t_rel_s": k.reference.t_rel.tolist(), "p_pa": k.reference.p.tolist()}
            for k in self.kept.values()]}

    def write(self, data: dict[str, Any]) -> None:
        """Atomically: a temporary file beside it, forced to disk, renamed over the old one
        (and the directory forced, so the rename survives a power cut)."""
        path = self.path
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        try:
            with open(tmp, "w", encoding="utf-8") as f:
                json.dump(data, f, separators=(",", ":"))
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)

    def status(self) -> dict[str, Any]:
        now = time.time()
        return {"file": None if self.path is None else str(self.path),
                "references": [{"p0_kpa": k.p0_kpa, "cycle_id": k.reference.cycle_id,
                                "age_s": max(0.0, now - k.measured_unix_s), "source": k.source}
                               for k in sorted(self.kept.values(), key=lambda k: k.p0_kpa)],
                "refused": list(self.refused), "error": self.error}
