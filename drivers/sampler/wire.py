"""Messages between the sampler process and the daemon (ZeroMQ multipart, no pickle).

Frame 1 is a small UTF-8 JSON header with ``v`` (protocol version) and ``type``;
``block`` messages add three frames of raw float64 in the byte order the header names
(``dtype``): the read times ``t_s`` (n), the values (n x channels, row-major) and the
lateness (n). Sampler -> daemon (PUSH/PULL): ``hello``, ``block``, ``heartbeat``,
``link_lost``, ``implausible``, ``fatal``, ``stopped``. Daemon -> sampler (PUSH/PULL): ``stop``.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from typing import Any

from fluidsense.common.errors import DriverError

PROTOCOL = 1
DTYPE = "<f8" if sys.byteorder == "little" else ">f8"

#: sampler exit codes
EXIT_STOPPED = 0
EXIT_CRASHED = 1  # an uncaught exception (Python's own code)
EXIT_CONFIG = 2  # bad poller spec or channel count
EXIT_OPEN = 3  # poller.open() failed
EXIT_LINK_LOST = 4
EXIT_IMPLAUSIBLE = 5  # the poller's device said what cannot be true


def encode(kind: str, fields: dict[str, Any] | None = None, arrays: Sequence[Any] = ()) -> list[Any]:
    header = {"v": PROTOCOL, "type": kind, **(fields or {})}
    return [json.dumps(header, separators=(",", ":")).encode(), *arrays]


def decode(frames: Sequence[bytes]) -> tuple[dict[str, Any], list[bytes]]:
    try:
        header = json.loads(frames[0])
    except (ValueError, IndexError) as exc:
        raise DriverError(f"sampler sent an unreadable message header: {exc}") from exc
    if not isinstance(header, dict) or header.get("v") != PROTOCOL or "type" not in header:
        raise DriverError(f"sampler message with an unknown protocol: {str(header)[:200]}")
    return header, list(frames[1:])
