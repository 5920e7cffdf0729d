"""Reading a recording in file order.

A file holds, in the order the controller produced them: a ``fluidsense`` metadata
record, the cell config (the first message, so a file replays on its own), the free-air
references the controller held when the file was opened, then every sample block and
every controller event (schema.py). The reader reads a file cut off by a kill up to its
last complete record and says how many bytes it left; a file that is not a recording,
or is garbled, raises ``RecordingError`` naming the file. See docs/recording.md.
"""

from __future__ import annotations

import json
import logging
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fluidsense.common.errors import RecordingError
from fluidsense.common.files import nested_within, one_line, open_regular
from mcap.exceptions import EndOfFile, InvalidMagic
from mcap.records import Channel, Chunk, Footer, Message, Metadata
from mcap.stream_reader import StreamReader

from .chunks import MAX_CHUNK_BYTES, ChunkError, chunk_records
from .messages import block_from_payload
from .schema import CONFIG, FORMAT, FORMAT_VERSION, METADATA_NAME, SAMPLES

log = logging.getLogger(__name__)

# events and the config are a few levels deep (a cycle result, the wiring of a sensor)
MAX_JSON_DEPTH = 32


def _one_line(exc: Exception) -> str:
    return one_line(" ".join(f"{type(exc).__name__}: {exc}".split()))


@dataclass(frozen=True)
class Record:
    """One message of a recording: ``topic`` without its slash, ``t_s`` sample time,
    ``data`` a SampleBlock for ``samples``, else the decoded JSON object."""

    topic: str
    t_s: float
    data: Any


class _Exact:
    """A file whose reads return all the bytes asked for or raise EndOfFile: the MCAP
    stream reader then stops cleanly at a record cut off by a kill instead of parsing
    half a record."""

    def __init__(self, f, size: int):
        self._f = f
        self._size = size
        self.pos = 0

    def read(self, n: int = -1) -> bytes:
        if n is not None and n > self._size - self.pos:  # a length field beyond the end: a cut-off record
            raise EndOfFile()
        data = self._f.read(n)
        if n is not None and n > 0 and len(data) < n:
            raise EndOfFile()
        self.pos += len(data)
        return data


class RecordingReader:
    """Reads a recording in file order, tolerating a cut-off tail (a writer killed with
    SIGKILL): ``complete`` tells whether the writer closed the file, ``dropped_bytes`` how
    much of a partial record was left at the end. Reading is lazy: ``records()`` once."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        # a FIFO, a device or a directory is refused before it is read (it would block or never end)
        self._file = open_regular(self.path, RecordingError)
        self.size = os.fstat(self._file.fileno()).st_size
        self._stream = _Exact(self._file, self.size)
        self._good = 0
        self._topics: dict[int, str] = {}
        self.metadata: dict[str, str] = {}
        self.complete = False
        self.dropped_bytes = 0
        self._head: list[Record] = []
        self._iter = self._read()
        try:
            self.config = self._find_config()
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> RecordingReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _find_config(self) -> dict[str, Any]:
        not_ours = RecordingError(f"{self.path}: an MCAP file but not a fluidsense recording (no "
                                  f"'{METADATA_NAME}' metadata before its data)")
        for rec in self._iter:
            if rec.topic == CONFIG:
                if not self.metadata:
                    raise not_ours
                return rec.data
            self._head.append(rec)
        if self.complete:
            raise not_ours if not self.metadata else RecordingError(f"{self.path}: has no cell config")
        raise RecordingError(f"{self.path}: cut off after {self.size} bytes, before its cell config: "
                             "nothing to replay")

    def records(self) -> Iterator[Record]:
        """Every message after the config, in the order it was written."""
        head, self._head = self._head, []
        yield from head
        yield from self._iter

    def _read(self) -> Iterator[Record]:
        records = self._records()
        while True:
            try:
                item = next(records)
            except StopIteration:
                return
            except EndOfFile:
                self.dropped_bytes = self.size - self._good
                log.info("%s: ends without a footer; %d bytes of a partial record ignored", self.path,
                         self.dropped_bytes)
                return
            except InvalidMagic as exc:
                raise RecordingError(f"{self.path}: not an MCAP file (bad magic bytes)") from exc
            except ChunkError as exc:
                raise RecordingError(f"{self.path}: garbled near byte {self._stream.pos}: {exc}") from exc
            except Exception as exc:  # noqa: BLE001 - anything the parser trips on is a garbled file
                raise RecordingError(f"{self.path}: garbled near byte {self._stream.pos}: "
                                     f"{_one_line(exc)}") from exc
            self._good = self._stream.pos
            rec = self._dispatch(item)
            if rec is not None:
                yield rec

    def _records(self) -> Iterator[Any]:
        """Every MCAP record in file order, chunks opened within bounds (chunks.py)."""
        # no record may be larger than a chunk this reader would open
        stream = StreamReader(self._stream, validate_crcs=True, emit_chunks=True, record_size_limit=MAX_CHUNK_BYTES)
        for item in stream.records:
            if isinstance(item, Chunk):
                yield from chunk_records(item)
            else:
                yield item

    def _dispatch(self, item: Any) -> Record | None:
        if isinstance(item, Message):
            return self._decode(item)
        if isinstance(item, Channel):
            self._topics[item.id] = item.topic.removeprefix("/")
        elif isinstance(item, Metadata) and item.name == METADATA_NAME:
            self._check_format(item.metadata)
        elif isinstance(item, Footer):
            self.complete = True
        return None

    def _check_format(self, meta: dict[str, str]) -> None:
        if meta.get("format") != FORMAT:
            raise RecordingError(f"{self.path}: not a fluidsense recording (format {meta.get('format')!r})")
        found = meta.get("format_version", "?")
        if found != str(FORMAT_VERSION):
            raise RecordingError(f"{self.path}: recording format version {found}; this fluidsense reads "
                                 f"version {FORMAT_VERSION}")
        self.metadata = dict(meta)

    def _decode(self, msg: Message) -> Record:
        topic = self._topics.get(msg.channel_id)
        try:
            if topic is None:
                raise KeyError(f"message on unknown channel {msg.channel_id}")
            data = json.loads(msg.data)
            if not isinstance(data, dict):
                raise ValueError(f"expected a JSON object, got {type(data).__name__}")
            if topic == SAMPLES:
                block = block_from_payload(data)
                return Record(SAMPLES, block.t_end, block)
            if not nested_within(data, MAX_JSON_DEPTH):
                raise ValueError(f"nested more than {MAX_JSON_DEPTH} levels deep")
            t_s = data.get("t_s", 0.0)
            if isinstance(t_s, bool) or not isinstance(t_s, (int, float)) or not math.isfinite(t_s):
                raise ValueError(f"t_s: expected a finite number, got {str(t_s)[:40]}")
            return Record(topic, float(t_s), data)
        except (ValueError, KeyError, TypeError, AttributeError, RecursionError) as exc:
            raise RecordingError(f"{self.path}: garbled message on {topic or '?'} near byte {self._stream.pos}: "
                                 f"{_one_line(exc)}") from exc
