"""The recording sink: the daemon's samples, events and config in MCAP files on disk.

The daemon runs this sink on a thread of its own behind a bounded queue
(controller/telemetry/queued.py): the sample loop never waits on compression or the
disk; in real time a full queue drops and counts (``status`` -> ``sinks``), in virtual
time it waits.

Flush guarantee: every ``flush_s`` of sample time the open chunk is closed and handed to
the OS, so a daemon killed with SIGKILL loses at most the last ``flush_s`` plus what was
still queued (normally a block or two; tests/unit/test_recording.py); with ``fsync`` another
worker thread also forces it to storage. A file is started between cycles once it passes
``max_file_mb`` or covers ``max_file_s`` of sample time (the MCAP writer keeps an index
entry per flushed chunk in memory until the file is closed: ~1 KB per ``flush_s``, 28 MB
over 8 h in one file, found by python -m lab bench soak); each file carries the config and
the references it needs to replay on its own. A write error or a nearly full disk logs,
closes what can be closed and drops the sink (the telemetry's Sink contract): control
goes on without recording. The controller's telemetry feeds it; it knows nothing of the
controller (the drivers' layer cannot), only the format.
"""

from __future__ import annotations

import logging
import shutil
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from fluidsense.common.errors import ConfigError, RecordingError
from fluidsense.common.samples import SampleBlock

from ..base import SampleSource
from ..sampler.realtime import share_loop_priority
from .config import RecordingConfig
from .schema import REFERENCE
from .writer import RecordingWriter

log = logging.getLogger(__name__)

MB = 2**20


class HeldReference(Protocol):
    """A free-air reference as the controller holds it (controller/cycles/analysis.py's
    ``Reference``)."""

    cycle_id: int
    t_rel: np.ndarray  # s since the valve opened
    p: np.ndarray  # offset-corrected actuator pressure, Pa


def new_path(directory: Path, now: float | None = None) -> Path:
    """``fluidsense-YYYYmmdd-HHMMSS.mcap`` (local time) in ``directory``, with a suffix
    ``_001``, ``_002`` ... if that name is taken: a recording is never overwritten (the writer
    also opens with O_EXCL). ``_`` sorts after ``.``, so names sort in the order written."""
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(now))
    path = directory / f"fluidsense-{stamp}.mcap"
    n = 1
    while path.exists():
        path = directory / f"fluidsense-{stamp}_{n:03d}.mcap"
        n += 1
    return path


class RecordingSink:
    """Writes what the controller sees: a sink of the controller's telemetry (its
    ``on_block``, ``on_event``, ``flush`` and ``close``). ``config``: the cell config as
    JSON, with its JSON schema, at the top of every file; ``references`` returns the
    controller's free-air references, written after it (so a later file replays on its
    own)."""

    def __init__(self, settings: RecordingConfig, config: dict[str, Any], config_schema: dict[str, Any],
                 source: SampleSource | None = None,
                 references: Callable[[], dict[float, HeldReference]] = dict):
        self.rc = settings
        self.dir = Path(self.rc.dir).expanduser()
        self._references = references
        self._meta = {} if source is None else {"rate_hz": repr(float(source.rate_hz)),
                                                "channels": ",".join(source.channels),
                                                "virtual": str(bool(source.virtual)).lower()}
        self._config, self._schema = config, config_schema
        self._t0_ns = time.time_ns()  # sample time 0 on the wall clock (for viewers' timelines)
        self._sync_pool = ThreadPoolExecutor(1, thread_name_prefix="recording-fsync",
                                             initializer=share_loop_priority) if self.rc.fsync else None
        self._sync_job: Future | None = None
        self._in_cycle = False
        self._flushed_t = 0.0
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            self._check_space()
            self._writer = self._open(0.0)
        except (OSError, RecordingError) as exc:
            self._stop_pool()
            raise ConfigError(f"recording.dir: cannot record in {self.dir}: {exc} "
                              "(fluidsense run --no-record runs without recording)") from exc

    @property
    def t0_unix_ns(self) -> int:
        """The wall clock at sample time 0: the live view shares it, so its times are the file's."""
        return self._t0_ns

    @property
    def path(self) -> Path:
        return self._writer.path

    # ------------------------------------------------------------ the telemetry's Sink
    def on_block(self, block: SampleBlock) -> None:
        self._guard(self._writer.write_block, block)
        if block.t_end - self._flushed_t >= self.rc.flush_s:
            self.flush(block.t_end)
            if not self._in_cycle and self._full(block.t_end):
                self._rotate(block.t_end)

    def on_event(self, topic: str, t_s: float, payload: dict[str, Any]) -> None:
        if topic == "cycle_start":
            # between two cycles every block of the last one is written: the place to start
            # a new file (in virtual time no block comes between cycles)
            if self._full(t_s):
                self._rotate(t_s)
            self._in_cycle = True
        elif topic == "cycle":
            self._in_cycle = False
        self._guard(self._writer.write_event, topic, t_s, payload)

    def flush(self, t_s: float) -> None:
        self._flushed_t = t_s
        self._guard(self._writer.flush)
        self._sync()
        self._check_space()

    def close(self) -> None:
        try:
            self._wait_sync()
            self._writer.close()
            log.info("recording closed: %s (%.1f MB)", self._writer.path, self._writer.path.stat().st_size / MB)
        except OSError as exc:
            raise RecordingError(f"{self._writer.path}: closing failed: {exc}") from exc
        finally:
            self._stop_pool()

    # ------------------------------------------------------------ files
    def _full(self, t_s: float) -> bool:
        return self._writer.size >= self.rc.max_file_mb * MB or t_s - self._file_t0 >= self.rc.max_file_s

    def _open(self, t_s: float) -> RecordingWriter:
        self._file_t0 = t_s
        path = new_path(self.dir)
        writer = RecordingWriter(path, self._t0_ns, self._meta, self.rc.compression)
        try:
            writer.write_config(self._config, self._schema)
            for key, ref in sorted(self._references().items()):
                writer.write_event(REFERENCE, t_s, {"key_kpa": key, "cycle_id": ref.cycle_id,
                                                    "t_rel_s": ref.t_rel.tolist(), "p_pa": ref.p.tolist()})
            writer.flush()  # a file killed in its first second still names its config
        except BaseException:
            writer.abandon()
            raise
        log.info("recording to %s", path.resolve())
        return writer

    def _rotate(self, t_s: float) -> None:
        old, old_t0 = self._writer, self._file_t0
        self._wait_sync()
        self._guard(old.close)
        try:
            self._writer = self._open(t_s)
        except OSError as exc:
            self._stop_pool()
            raise RecordingError(f"{self.dir}: cannot start a new recording: {exc}; recording stopped") from exc
        log.info("recording: %s holds %.1f MB over %.0f s (limits %.0f MB, %.0f s), continuing in %s",
                 old.path.name, old.path.stat().st_size / MB, t_s - old_t0, self.rc.max_file_mb, self.rc.max_file_s,
                 self._writer.path.name)

    def _guard(self, write: Callable[..., None], *args: Any) -> None:
        """A write error stops the recording (the file keeps what was flushed) and is
        raised for the controller to log and drop this sink."""
        try:
            write(*args)
        except OSError as exc:
            self._fail(exc)

    def _fail(self, exc: OSError) -> None:
        self._stop_pool()
        self._writer.abandon()
        raise RecordingError(f"{self._writer.path}: write failed: {exc}; recording stopped") from exc

    def _check_space(self) -> None:
        free = shutil.disk_usage(self.dir).free
        if free >= self.rc.min_free_mb * MB:
            return
        msg = f"{self.dir}: only {free / MB:.0f} MB free (recording.min_free_mb = {self.rc.min_free_mb:g})"
        writer = getattr(self, "_writer", None)
        if writer is None:  # at start: the caller refuses to start
            raise RecordingError(msg)
        self._wait_sync()
        self._stop_pool()
        writer.close()
        raise RecordingError(f"{msg}; recording stopped, {writer.path} closed")

    # ------------------------------------------------------------ fsync off the loop
    def _sync(self) -> None:
        if self._sync_pool is None:
            return
        job = self._sync_job
        if job is not None and job.done() and isinstance(job.exception(), OSError):
            self._fail(job.exception())
        if job is None or job.done():  # one at a time: a slow disk delays syncs, never the loop
            self._sync_job = self._sync_pool.submit(self._writer.sync)

    def _wait_sync(self) -> None:
        if self._sync_job is not None:
            try:
                self._sync_job.result()
            except OSError as exc:
                log.error("recording: fsync of %s failed: %s", self._writer.path, exc)
            self._sync_job = None

    def _stop_pool(self) -> None:
        if self._sync_pool is not None:
            self._sync_pool.shutdown(wait=True)
            self._sync_pool = None

