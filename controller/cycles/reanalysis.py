"""Reanalysis (``fluidsense replay``): the controller's cycle analysis run again on a
recording (drivers/recording/), each cycle compared with its live result.

Valves cannot be commanded in a recording, so the sequencer is not re-run. What a cycle's
features depend on is replayed instead: the recorded samples (through the replay
driver, block by block as they were delivered), the recorded control decisions (each
cycle's start with its P0, label and reference flag; its transitions, which give
t_start, t_open and t_end and an abort's reason) and the recorded config's sequence. The
cycle's blocks are those the live recorder took: after the start, up to the sample time
at which the result was emitted. The features then come from the same
``analysis.analyse`` with the same reference handling as the controller
(``store_reference`` cycles make the reference for later cycles at the same P0). For a
complete cycle the replayed result must equal the recorded one, every number to within
REPRODUCIBLE (below); a cycle cut off by the end of the recording is reported as
incomplete with what its samples give.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from fluidsense.common.hardware import Circuit
from fluidsense.common.errors import EndOfRecording, RecordingError
from fluidsense.common.files import one_line
from fluidsense.controller.config import CellConfig, SequenceConfig, validate
from fluidsense.controller.cycles.analysis import (
    CycleResult,
    CycleTrace,
    Reference,
    analyse,
    make_reference,
)
from fluidsense.controller.cycles.analysis import reference_key
from fluidsense.controller.cycles.runner import freeze_for
from fluidsense.drivers.recording.backend import ReplaySource
from fluidsense.drivers.recording.messages import to_json
from fluidsense.drivers.recording.reader import Record
from fluidsense.drivers.recording.schema import REFERENCE

log = logging.getLogger(__name__)


def comparable(result: dict[str, Any]) -> dict[str, Any]:
    """A result as the recording keeps it (JSON: non-finite numbers are null)."""
    return json.loads(to_json(result))


@dataclass
class ReplayedCycle:
    cycle_id: int
    label: str | None
    complete: bool  # the recording holds the live result
    replay: dict[str, Any]
    live: dict[str, Any] | None
    differences: list[str] = field(default_factory=list)

    @property
    def agree(self) -> bool | None:
        return None if self.live is None else not self.differences

    def to_dict(self) -> dict[str, Any]:
        return {"cycle_id": self.cycle_id, "label": self.label,
                "status": "complete" if self.complete else "incomplete", "agree": self.agree,
                "differences": self.differences, "replay": self.replay, "live": self.live}


@dataclass
class ReplayReport:
    file: str
    closed: bool  # the writer closed the file (else it was killed: read up to the last complete record)
    dropped_bytes: int
    blocks: int = 0
    samples: int = 0
    t_first_s: float | None = None
    t_last_s: float | None = None
    cycles: list[ReplayedCycle] = field(default_factory=list)

    @property
    def agree(self) -> bool:
        return all(c.agree is not False for c in self.cycles)

    def to_dict(self) -> dict[str, Any]:
        return {"file": self.file, "closed": self.closed, "dropped_bytes": self.dropped_bytes,
                "blocks": self.blocks, "samples": self.samples, "t_first_s": self.t_first_s,
                "t_last_s": self.t_last_s, "agree": self.agree, "cycles": [c.to_dict() for c in self.cycles]}


@dataclass
class _Cycle:
    """One cycle being rebuilt from its records."""

    cycle_id: int
    p0_pa: float
    label: str | None
    store_reference: bool
    t_start: float
    t_open: float | None = None
    t_idle: float | None = None  # the sequencer's t_end (VENT -> IDLE)
    idle_reason: str | None = None
    aborted: str | None = None
    t_result: float | None = None  # when the live result was emitted
    live: dict[str, Any] | None = None
    recorder: CycleTrace = field(default_factory=CycleTrace)


class BadEvent(ValueError):
    """A recorded event without what replay reads from it: ``topic.field: reason``."""


def _number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _numbers(v: Any) -> bool:
    return isinstance(v, list) and all(_number(x) for x in v)


def _integer(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _text_or_none(v: Any) -> bool:
    return v is None or isinstance(v, str)


# What replay reads from each event topic, and what it must be: a recording is untrusted
# input, and a null where a number belongs must be a clear error, not a TypeError deep
# in the pipeline.
_READS = {
    REFERENCE: {"key_kpa": (_number, "a finite number"), "cycle_id": (_integer, "an integer"),
                "t_rel_s": (_numbers, "a list of finite numbers"), "p_pa": (_numbers, "a list of finite numbers")},
    "cycle_start": {"cycle_id": (_integer, "an integer"), "p0_pa": (_number, "a finite number"),
                    "label": (_text_or_none, "a string or null"),
                    "store_reference": (lambda v: isinstance(v, bool), "true or false")},
    "state": {"to": (lambda v: isinstance(v, str), "a string"), "at_s": (_number, "a finite number"),
              "reason": (lambda v: isinstance(v, str), "a string")},
    "cycle": {"aborted": (_text_or_none, "a string or null")},
}


def check_event(rec: Record) -> None:
    for key, (ok, what) in _READS.get(rec.topic, {}).items():
        if rec.topic == "cycle" and key not in rec.data:
            continue
        if key not in rec.data:
            raise BadEvent(f"{rec.topic}.{key}: missing (at t = {rec.t_s:g} s)")
        if not ok(rec.data[key]):
            raise BadEvent(f"{rec.topic}.{key}: expected {what}, got {one_line(str(rec.data[key])[:40])} "
                           f"(at t = {rec.t_s:g} s)")
    if rec.topic == REFERENCE and len(rec.data["t_rel_s"]) != len(rec.data["p_pa"]):
        raise BadEvent(f"{rec.topic}.p_pa: {len(rec.data['p_pa'])} pressures for {len(rec.data['t_rel_s'])} times")


class CycleReplay:
    """Rebuilds cycles from a recording's records in file order (no I/O)."""

    def __init__(self, seq: SequenceConfig, circuit: Circuit | None = None, freeze_s: float | None = None):
        """``circuit``: the profile's (the object's bound); ``freeze_s``: as the controller
        had it (runner.freeze_for)."""
        self.seq, self.circuit = seq, circuit
        self.freeze_s = freeze_s
        self.references: dict[float, Reference] = {}
        self.cycles: list[ReplayedCycle] = []
        self._open: _Cycle | None = None
        self.t_last: float | None = None

    def on_event(self, rec: Record) -> None:
        check_event(rec)
        data, cur = rec.data, self._open
        if rec.topic == REFERENCE:  # held by the controller when the file was opened
            self.references[data["key_kpa"]] = Reference(np.asarray(data["t_rel_s"], dtype=float),
                                                         np.asarray(data["p_pa"], dtype=float), data["cycle_id"])
        elif rec.topic == "cycle_start":
            if cur is not None:
                self._finish()
            self._open = _Cycle(data["cycle_id"], data["p0_pa"], data["label"], data["store_reference"], rec.t_s)
        elif cur is None or data.get("cycle_id") != cur.cycle_id or cur.live is not None:
            return
        elif rec.topic == "state":
            self._transition(cur, data)
        elif rec.topic == "cycle":
            cur.live, cur.t_result = data, rec.t_s

    @staticmethod
    def _transition(cur: _Cycle, tr: dict[str, Any]) -> None:
        # the sequencer keeps the first reason a cycle was aborted or faulted for
        if tr["to"] == "actuate":
            cur.t_open = tr["at_s"]
        elif tr["to"] == "vent" and tr["reason"].startswith("abort: "):
            cur.aborted = cur.aborted or tr["reason"].removeprefix("abort: ")
        elif tr["to"] == "fault":
            cur.aborted = cur.aborted or tr["reason"]
        elif tr["to"] == "idle":
            cur.t_idle, cur.idle_reason = tr["at_s"], tr["reason"]

    def on_block(self, block) -> None:
        self.t_last = block.t_end
        cur = self._open
        if cur is not None and cur.t_result is not None and block.t_end > cur.t_result:
            self._finish()
            cur = None
        if cur is not None and block.t_end > cur.t_start:
            cur.recorder.add(block)

    def finish(self) -> list[ReplayedCycle]:
        if self._open is not None:
            self._finish()
        return self.cycles

    def _finish(self) -> None:
        cur, self._open = self._open, None
        result = self._analyse(cur)
        key = reference_key(cur.p0_pa)
        if cur.live is not None and cur.store_reference and result.ok:  # as Controller._finish_cycle
            self.references[key] = make_reference(result)
            result.is_reference = True
        replay = comparable(result.to_dict())
        diffs = [] if cur.live is None else _differences(replay, cur.live)
        self.cycles.append(ReplayedCycle(cur.cycle_id, cur.label, cur.live is not None, replay, cur.live, diffs))

    def _analyse(self, cur: _Cycle) -> CycleResult:
        """As Controller._analyse(final=True) for a finished cycle; a cut-off one is
        analysed like a running one (no end time)."""
        t, values = cur.recorder.arrays()
        ref = None if cur.store_reference else self.references.get(reference_key(cur.p0_pa))
        t_end = (cur.t_idle or cur.t_result) if cur.live is not None else None
        aborted = cur.aborted
        if aborted is None and cur.live is not None and cur.idle_reason in (None, "aborted"):
            # an abort while already venting leaves no transition of its own: only its reason
            # is taken from the result, never a feature
            aborted = cur.live.get("aborted")
        try:
            return analyse(cur.cycle_id, cur.p0_pa, cur.t_start, cur.t_open, t_end, t, values, cur.recorder.channels,
                           self.seq, ref, aborted=aborted, label=cur.label, missed=cur.recorder.missed,
                           circuit=self.circuit, freeze_s=self.freeze_s)
        except ValueError as exc:
            return CycleResult(cur.cycle_id, cur.p0_pa, cur.t_start, cur.t_open, cur.t_result or self.t_last,
                               aborted=f"analysis failed: {exc}", missed=cur.recorder.missed)


# How far a replayed number may lie from the recorded one and still be the same result:
# relative 1e-9, and 1e-9 absolute (kPa, s, ml) for the numbers near zero that are
# differences of large ones (dP of a free grip: 1e-3 kPa out of 35 kPa minus 35 kPa). The same analysis on the same float64 samples gives the same bits on the
# machine that recorded them, but another CPU may not: numpy and OpenBLAS choose their
# SIMD kernels at run time, and a sum or an interpolation taken in another order differs
# in its last bits (a contact time recorded as 0.15123473920597566 s replays on an AVX2
# kernel as ...563, 2e-16 relative). Any change of the pipeline (a window, a threshold, a
# sample more or less) moves a feature by far more than 1e-9: at least a sensor quantum
# (16 Pa against 35 kPa, 5e-4) or a sample period (1 ms against 0.15 s).
REPRODUCIBLE = 1e-9


def _same(a: Any, b: Any) -> bool:
    """Equal, numbers to within REPRODUCIBLE (inside lists and mappings too: the windows)."""
    if isinstance(a, float) and isinstance(b, float):
        return a == b or math.isclose(a, b, rel_tol=REPRODUCIBLE, abs_tol=REPRODUCIBLE)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    return a == b


#: fields of a cycle's result newer than some recordings: one recorded without them has
#: nothing to compare them with (a recording from before a field existed still agrees)
NEWER_FIELDS = frozenset({"unchanged_s", "unreliable", "t_c_min_s", "object", "object_note", "object_bound_kpa"})


def _differences(replay: dict[str, Any], live: dict[str, Any]) -> list[str]:
    keys = sorted((set(replay) - (NEWER_FIELDS - set(live))) | (set(live) - {"t_s"}))
    return [k for k in keys if not _same(replay.get(k), live.get(k))]


async def replay_file(path: str | Path) -> ReplayReport:
    """Replay a recording (read up to its last complete record) and compare every cycle."""
    source = ReplaySource(path)
    async with source:
        try:
            return await _replay(source, path)
        except BadEvent as exc:
            raise RecordingError(f"{path}: {exc}") from exc


async def _replay(source: ReplaySource, path: str | Path) -> ReplayReport:
    """The replay proper, on a set-up source."""
    cfg = validate(CellConfig, source.config, path, prefix="(recorded config) ")
    pipeline = CycleReplay(cfg.profile.sequence, cfg.profile.circuit, freeze_for(cfg.profile, cfg.supervision.freeze_s))
    report = ReplayReport(str(path), closed=False, dropped_bytes=0)
    while True:
        try:
            block = await source.read_block()
        except EndOfRecording:
            break
        for rec in source.drain_events():
            pipeline.on_event(rec)
        pipeline.on_block(block)
        report.blocks += 1
        report.samples += len(block)
        if report.t_first_s is None:
            report.t_first_s = float(block.t[0])
    for rec in source.drain_events():
        pipeline.on_event(rec)
    report.t_last_s = pipeline.t_last
    report.cycles = pipeline.finish()
    report.closed, report.dropped_bytes = source.reader.complete, source.reader.dropped_bytes
    return report
