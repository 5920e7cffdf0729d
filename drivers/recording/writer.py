"""Writing a recording: an MCAP file of JSON messages, each channel with its JSON schema
(schema.py says what a file holds, docs/recording.md why MCAP).

MCAP is append-only and chunked: a writer killed mid-file leaves every chunk it had
flushed readable (reader.py reads such a file up to its last complete record).
"""

from __future__ import annotations

import json
import os
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from fluidsense.common.samples import SampleBlock
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

from .messages import block_payload, to_json
from .schema import (
    CONFIG,
    FORMAT,
    FORMAT_VERSION,
    METADATA_NAME,
    SAMPLES,
    SCHEMAS,
    event_schema,
)

# chunks close on flush(), not on size: this only bounds a chunk if flushes stop coming
CHUNK_BYTES = 8 * 2**20
COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}


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
