"""MCAP chunks from untrusted files, decompressed within bounds.

The mcap library decompresses a chunk in one call: zstd into a buffer as large as the
chunk says it needs (a 64-bit field), lz4 with no limit at all. A chunk of a few hundred
KB of zstd can expand to gigabytes (a decompression bomb): the reader then hangs or runs
out of memory. Here a chunk is refused when it declares more than ``MAX_CHUNK_BYTES`` or
more than ``MAX_RATIO`` times its compressed size, and decompression is streamed and
stops one byte past what the chunk declared, so no chunk ever costs more than
``MAX_CHUNK_BYTES`` of memory or ``MAX_RATIO`` times its own size of work: a whole file
is read in time proportional to its size.
"""

from __future__ import annotations

import io

from mcap.records import Chunk
from mcap.stream_reader import breakup_chunk

# fluidsense closes a chunk at every flush (1 s of samples, ~60 KB) or at 8 MB
# (writer.py CHUNK_BYTES); 64 MB leaves room for other writers' chunks.
MAX_CHUNK_BYTES = 64 * 2**20
# the daemon's JSON compresses about 5:1 with zstd (measured on a recording of cycles);
# even constant readings keep changing timestamps, so 200:1 is far beyond real data
MAX_RATIO = 200
_PIECE = 2**20


class ChunkError(ValueError):
    """A chunk that is refused or cannot be decompressed; the message is the reason."""


def _zstd(data: bytes, limit: int) -> bytes:
    import zstandard

    out, total = [], 0
    with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data)) as reader:
        while total <= limit:
            piece = reader.read(min(_PIECE, limit + 1 - total))
            if not piece:
                break
            out.append(piece)
            total += len(piece)
    return b"".join(out)


def _lz4(data: bytes, limit: int) -> bytes:
    import lz4.frame

    dec = lz4.frame.LZ4FrameDecompressor()
    out = dec.decompress(data, max_length=limit + 1)
    if len(out) <= limit and not dec.eof:
        raise ChunkError("lz4 frame cut off")
    return out


def decompress(chunk: Chunk) -> bytes:
    """The records of a chunk, uncompressed, or ChunkError."""
    declared, size = chunk.uncompressed_size, len(chunk.data)
    if declared > MAX_CHUNK_BYTES:
        raise ChunkError(f"a chunk declares {declared} bytes uncompressed, more than the {MAX_CHUNK_BYTES} "
                         "this reader accepts")
    if chunk.compression in ("", "none"):
        data = chunk.data
    elif declared > MAX_RATIO * max(size, 1):
        raise ChunkError(f"a chunk of {size} bytes declares {declared} uncompressed, more than {MAX_RATIO} "
                         "times its size: refused as a decompression bomb")
    elif chunk.compression == "zstd":
        data = _zstd(chunk.data, declared)
    elif chunk.compression == "lz4":
        data = _lz4(chunk.data, declared)
    else:
        raise ChunkError(f"unsupported chunk compression {chunk.compression[:20]!r}")
    if len(data) != declared:
        raise ChunkError(f"a chunk decompresses to {'more than ' if len(data) > declared else ''}{len(data)} "
                         f"bytes, not the {declared} it declares")
    return data


def chunk_records(chunk: Chunk, validate_crc: bool = True) -> list:
    """The records inside a chunk (schemas, channels, messages), within the bounds above."""
    data = decompress(chunk)
    plain = Chunk(compression="", data=data, message_start_time=chunk.message_start_time,
                  message_end_time=chunk.message_end_time, uncompressed_crc=chunk.uncompressed_crc,
                  uncompressed_size=len(data))
    return breakup_chunk(plain, validate_crc=validate_crc)


__all__ = ["ChunkError", "MAX_CHUNK_BYTES", "MAX_RATIO", "chunk_records", "decompress"]
