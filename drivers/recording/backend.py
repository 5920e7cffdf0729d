"""The replay driver (``driver: {kind: replay}``): a recording's sample blocks, as they
were delivered, in virtual time (imported only when a config selects it).

The source hands over the recorded blocks one by one, unchanged; the events recorded
between two blocks (transitions, results, commands) wait in ``drain_events()`` for a
consumer that wants them (``fluidsense replay``). Valves cannot be commanded in a
recording: the valve bank accepts commands and does nothing, and there is no regulator
or flow controller, so a controller on this backend can watch samples but not run cycles.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

from fluidsense.common.errors import EndOfRecording, RecordingError
from fluidsense.common.hardware import Hardware
from fluidsense.common.samples import SampleBlock

from ..backend import Backend
from ..base import SampleSource, ValveBank
from .reader import Record, RecordingReader
from .schema import SAMPLES

log = logging.getLogger(__name__)


class ReplaySource(SampleSource):
    virtual = True

    def __init__(self, path: str | Path, name: str = "replay"):
        super().__init__(name)
        self.path = Path(path)
        self.reader: RecordingReader | None = None
        self._records = iter(())
        self._events: list[Record] = []
        self.rate_hz = 0.0
        self.channels = ()
        self.last_t: float | None = None

    @property
    def config(self) -> dict[str, Any]:
        """The recorded cell config (JSON), once set up."""
        self._require_connected()
        return self.reader.config

    async def _setup(self) -> None:
        self.reader = RecordingReader(self.path)
        self._records = self.reader.records()
        meta = self.reader.metadata
        try:
            self.rate_hz = float(meta.get("rate_hz", 0.0))
        except ValueError:
            self.rate_hz = math.nan
        if not (math.isfinite(self.rate_hz) and self.rate_hz >= 0):
            self.reader.close()
            raise RecordingError(f"{self.path}: rate_hz: the recording's metadata gives {meta.get('rate_hz')!r}, "
                                 "not a sample rate")
        self.channels = tuple(c for c in meta.get("channels", "").split(",") if c)
        log.info("replaying %s", self.path)

    async def _stop(self) -> None:
        if self.reader is not None:
            self.reader.close()

    async def _read_block(self) -> SampleBlock:
        for rec in self._records:
            if rec.topic == SAMPLES:
                self.last_t = rec.t_s
                return rec.data
            self._events.append(rec)
        raise EndOfRecording(f"{self.path}: end of the recording"
                             + ("" if self.last_t is None else f" at t = {self.last_t:.3f} s"))

    def drain_events(self) -> list[Record]:
        """The events read since the last call (those recorded before the latest block)."""
        out, self._events = self._events, []
        return out


class ReplayValves(ValveBank):
    """Valves of a recording: positions are kept, nothing moves."""

    async def _set(self, valve: str, open: bool, t: float) -> None:
        log.debug("replay: valve %s -> %s at t=%.3f ignored (a recording cannot be commanded)", valve, open, t)


def build(cfg: Any, hw: Hardware, read_only: bool = False) -> Backend:
    """``read_only`` changes nothing: a recording is never written to."""
    return Backend(name="replay", source=ReplaySource(cfg.file), valves=ReplayValves("replay-valves",
                                                                                      hw.circuit.safe_valves))


__all__ = ["ReplaySource", "ReplayValves", "build"]
