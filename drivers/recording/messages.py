"""A recording's messages as JSON: how a sample block and an event become bytes, and a
recorded block becomes a SampleBlock again (checked: a recording is untrusted input).
The live view (controller/telemetry/live.py) sends the same bytes."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
from fluidsense.common.samples import SampleBlock


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
