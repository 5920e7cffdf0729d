"""A recording made by a virtual-time controller."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

from fluidsense.controller.config import CellConfig, load_cell_config
from fluidsense.daemon import app
from fluidsense.drivers.recording.reader import RecordingReader

from support.harness import sim_config


def cell(tmp_path: Path, **recording) -> CellConfig:
    cfg = load_cell_config(sim_config(tmp_path, clock="virtual"))
    return cfg.model_copy(update={"recording": cfg.recording.model_copy(update=recording)})


def the_file(tmp_path: Path) -> Path:
    files = sorted((tmp_path / "runs").glob("*.mcap"))
    assert len(files) == 1, files
    return files[0]


def record(tmp_path: Path, body, cfg: CellConfig | None = None, **recording):
    """Run ``body(controller)`` on a virtual-time controller that records (as the daemon)."""
    cfg = cfg or cell(tmp_path, **recording)

    async def main():
        async with app.controller(cfg, record=True) as ctrl:
            return await body(ctrl)

    return asyncio.run(main())


# hostile recordings (issue 14, item 5): chunks that decompress to far more than they say
def with_chunk(path: Path, good: Path, chunk) -> None:
    """A recording whose records after its config are one hand-made chunk."""
    from mcap.data_stream import RecordBuilder
    from mcap.writer import CompressionType, Writer

    with RecordingReader(good) as reader:
        meta, config = dict(reader.metadata), reader.config
    with open(path, "wb") as f:
        w = Writer(f, compression=CompressionType.NONE, use_chunking=False)
        w.start()
        w.add_metadata("fluidsense", meta)
        cid = w.register_channel("/config", "json", w.register_schema("config", "jsonschema", b"{}"))
        w.add_message(cid, log_time=0, data=json.dumps(config).encode(), publish_time=0)
        builder = RecordBuilder()
        chunk.write(builder)
        f.write(builder.end())


def _zeros_zstd(n: int) -> bytes:
    """zstd of n zero bytes, compressed piece by piece (never n bytes in memory)."""
    import zstandard

    chunker = zstandard.ZstdCompressor(level=1).chunker(size=n, chunk_size=2**22)
    zero, out = bytes(2**22), []
    for _ in range(n // len(zero)):
        out += chunker.compress(zero)
    return b"".join(out + list(chunker.finish()))


def _zeros_lz4(n: int) -> bytes:
    import lz4.frame

    c = lz4.frame.LZ4FrameCompressor()
    zero = bytes(2**22)
    return c.begin() + b"".join(c.compress(zero) for _ in range(n // len(zero))) + c.flush()


def _chunk(compression: str, data: bytes, declared: int):
    from mcap.records import Chunk

    return Chunk(compression=compression, data=data, message_start_time=0, message_end_time=0, uncompressed_crc=0,
                 uncompressed_size=declared)


BOMBS = {
    # a chunk that says it is huge: refused before any decompression
    "declared 4 GB": (lambda: _chunk("zstd", _zeros_zstd(2**24), 2**32),
                      "a chunk declares 4294967296 bytes uncompressed, more than the 67108864 this reader accepts"),
    # within the size cap but 60 MB from a few KB: refused by its ratio, before decompression
    "ratio": (lambda: _chunk("zstd", _zeros_zstd(60 * 2**20), 60 * 2**20),
              "more than 200 times its size: refused as a decompression bomb"),
    # a chunk that lies (says 1000 bytes, holds 256 MB): decompression stops at 1001
    "zstd lie": (lambda: _chunk("zstd", _zeros_zstd(2**28), 1000),
                 "a chunk decompresses to more than 1001 bytes, not the 1000 it declares"),
    "lz4 lie": (lambda: _chunk("lz4", _zeros_lz4(2**26), 1000),
                "a chunk decompresses to more than 1001 bytes, not the 1000 it declares"),
}
