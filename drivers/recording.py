"""The recording format: MCAP files of JSON messages, each channel with a JSON schema.

A file holds, in the order the controller produced them: a ``fluidsense`` metadata
record, the cell config (the first message, so a file replays on its own), the free-air
references the controller held when the file was opened, then every sample block
(``/samples``, SI units) and every controller event (``/state``, ``/cycle``, ``/fault``,
``/heartbeat``, ``/task``, ``/cycle_start``, ``/command``). Event payloads are those of
the published interface plus ``t_s``. See docs/recording.md.

MCAP is append-only and chunked: a writer killed mid-file leaves every chunk it had
flushed readable. The reader here reads such a file up to its last complete record and
says how many bytes it left; a file that is not a recording, or is garbled, raises
``RecordingError`` naming the file.
"""

from __future__ import annotations

import json
import logging
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import numpy as np
from fluidsense.common.errors import RecordingError
from fluidsense.common.files import nested_within, one_line, open_regular
from fluidsense.common.samples import SampleBlock
from mcap.exceptions import EndOfFile, InvalidMagic
from mcap.records import Channel, Chunk, Footer, Message, Metadata
from mcap.stream_reader import StreamReader
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

from .chunks import MAX_CHUNK_BYTES, ChunkError, chunk_records
from .recording_schema import CONFIG, SAMPLES, SCHEMAS, event_schema

log = logging.getLogger(__name__)

FORMAT = "fluidsense-recording"
FORMAT_VERSION = 1
METADATA_NAME = "fluidsense"
# chunks close on flush(), not on size: this only bounds a chunk if flushes stop coming
CHUNK_BYTES = 8 * 2**20
# events and the config are a few levels deep (a cycle result, the wiring of a sensor)
MAX_JSON_DEPTH = 32
COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}

def _finite(obj: Any) -> Any:
    """JSON has no NaN or infinity: they become null (and NaN again when read)."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, np.generic):
        return _finite(obj.item())
    if isinstance(obj, np.ndarray):
        return _finite(obj.tolist())
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


def to_json(obj: Any) -> bytes:
    """Compact JSON; floats keep every bit (repr), non-finite numbers become null."""
    try:  # the common case, without walking every value
        return json.dumps(obj, allow_nan=False, separators=(",", ":")).encode()
    except (ValueError, TypeError):
        return json.dumps(_finite(obj), allow_nan=False, separators=(",", ":"), default=str).encode()


def block_payload(block: SampleBlock) -> dict[str, Any]:
    return {"seq": block.seq, "times_s": block.t.tolist(), "channels": list(block.channels),
            "values": block.values.T.tolist(), "missed": block.missed, "late": block.late}


def _count(data: dict[str, Any], key: str) -> int:
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"{key}: expected a count, got {str(value)[:40]}")
    return value


def block_from_payload(data: dict[str, Any]) -> SampleBlock:
    """A recorded block, checked: times finite and increasing, one row of values (null:
    NaN) per channel; ValueError names the field otherwise."""
    t = np.asarray(data["times_s"], dtype=float)
    if t.ndim != 1 or len(t) == 0 or not np.isfinite(t).all() or (np.diff(t) <= 0).any():
        raise ValueError("times_s: expected increasing finite sample times")
    channels = data["channels"]
    if not isinstance(channels, list) or not all(isinstance(c, str) for c in channels):
        raise ValueError("channels: expected a list of names")
    values = np.asarray(data["values"], dtype=float)
    if values.shape != (len(channels), len(t)):
        raise ValueError(f"values: expected {len(channels)} rows of {len(t)}, got shape {values.shape}")
    return SampleBlock(_count(data, "seq"), t, np.ascontiguousarray(values.T), tuple(channels),
                       missed=_count(data, "missed"), late=_count(data, "late"))


def package_version() -> str:
    try:
        return version("fluidsense")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "unknown"


class RecordingWriter:
    """Appends messages to a new MCAP file (it refuses to overwrite one). ``flush()``
    closes the chunk in progress and hands the bytes to the OS; ``sync()`` forces them
    to storage."""

    def __init__(self, path: str | Path, t0_unix_ns: int, metadata: dict[str, str] | None = None,
                 compression: str = "zstd"):
        self.path = Path(path)
        self._t0_ns = t0_unix_ns
        self._file = open(self.path, "xb")  # noqa: SIM115 - closed in close(); "x": never overwrite
        try:
            self._mcap = Writer(self._file, chunk_size=CHUNK_BYTES, compression=COMPRESSION[compression])
            self._mcap.start(profile="", library=f"fluidsense {package_version()}; {LIBRARY_IDENTIFIER}")
            self._mcap.add_metadata(METADATA_NAME, {"format": FORMAT, "format_version": str(FORMAT_VERSION),
                                                    "fluidsense_version": package_version(),
                                                    "t0_unix_ns": str(t0_unix_ns), **(metadata or {})})
        except BaseException:
            self._file.close()
            raise
        self._channels: dict[str, int] = {}
        self._closed = False

    @property
    def size(self) -> int:
        """Bytes handed to the file so far (the open chunk not included)."""
        return self._file.tell()

    def fileno(self) -> int:
        return self._file.fileno()

    def _channel(self, topic: str, schema: dict[str, Any]) -> int:
        cid = self._channels.get(topic)
        if cid is None:
            sid = self._mcap.register_schema(schema.get("title", topic), "jsonschema", json.dumps(schema).encode())
            cid = self._mcap.register_channel("/" + topic, "json", sid)
            self._channels[topic] = cid
        return cid

    def _add(self, topic: str, t_s: float, data: bytes, schema: dict[str, Any]) -> None:
        # MCAP times are ns on a clock readers show as dates: the wall clock at sample time 0
        # plus sample time; the exact sample time is in the message itself
        ns = self._t0_ns + max(0, round(t_s * 1e9))
        self._mcap.add_message(self._channel(topic, schema), log_time=ns, data=data, publish_time=ns)

    def write_config(self, config: dict[str, Any], schema: dict[str, Any]) -> None:
        self._add(CONFIG, 0.0, to_json(config), schema)

    def write_block(self, block: SampleBlock) -> None:
        self._add(SAMPLES, block.t_end, to_json(block_payload(block)), SCHEMAS[SAMPLES])

    def write_event(self, topic: str, t_s: float, payload: dict[str, Any]) -> None:
        self._add(topic, t_s, to_json({"t_s": t_s, **payload}), event_schema(topic))

    def flush(self) -> None:
        self._mcap.flush()
        self._file.flush()

    def sync(self) -> None:
        os.fsync(self._file.fileno())

    def close(self) -> None:
        """Write the summary and footer (the file is then complete) and close."""
        if self._closed:
            return
        self._closed = True
        try:
            self._mcap.finish()
            self._file.flush()
            os.fsync(self._file.fileno())
        finally:
            self._file.close()

    def abandon(self) -> None:
        """Close without the summary (after a write error: whatever was flushed stays readable)."""
        self._closed = True
        try:
            self._file.close()
        except OSError:
            pass


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
        """Every MCAP record in file order, chunks opened within bounds (drivers/chunks.py)."""
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
