"""What a DAQmx read returned, checked before it becomes samples.

A read is the driver's word through NI's library, and still the device's: a library or
device at odds with the task (another task's channels, a block of the wrong length, a
sample clock faster than configured) must not become pressures. What cannot be true is
one DeviceProtocolError naming the field (the source restarts the acquisition, as after
an overflow):

- ``channels``: one list per channel for several channels, a flat list for one; another
  number of lists is another task's channels;
- ``samples``: every channel's list holds exactly the samples asked for (DAQmx returns
  all of them or raises at its timeout);
- ``values``: every sample is a finite number (DAQmx returns scaled volts or amps);
- ``rate``: the samples of one acquisition lead the host clock since its start by more
  than MAX_CLOCK_ERROR and LEAD_MARGIN_S: a sample clock faster than ``rate_hz`` (a
  sample cannot be read before it is taken, so a host that reads late never trips this).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from fluidsense.common.errors import DeviceProtocolError

from ..clockcheck import MAX_CLOCK_ERROR, lead_s

#: how late the host may take the acquisition's start (the task started on the driver's
#: thread before the host time was read; a loaded machine)
LEAD_MARGIN_S = 0.25


def block_rows(data: Any, channels: tuple[str, ...], n: int) -> np.ndarray:
    """DAQmx's read of ``n`` samples per channel -> (samples, channels) as floats."""
    nested = isinstance(data, list | tuple) and bool(data) and isinstance(data[0], list | tuple)
    if len(channels) > 1 and not nested:
        raise DeviceProtocolError(f"channels: a flat list of {_length(data)} values for {len(channels)} channels "
                                  f"({', '.join(channels)})", "channels")
    lists = list(data) if nested else [data]
    if len(lists) != len(channels):
        raise DeviceProtocolError(f"channels: {len(lists)} channel lists in a block, {len(channels)} in the task "
                                  f"({', '.join(channels)})", "channels")
    for name, values in zip(channels, lists):
        if _length(values) != n:
            raise DeviceProtocolError(f"samples: {_length(values)} samples of {name} in a block of {n}", "samples")
    try:
        rows = np.asarray(lists, dtype=float).T
    except (TypeError, ValueError) as exc:
        raise DeviceProtocolError(f"values: a block holds what is not a number: {exc}", "values") from exc
    bad = ~np.isfinite(rows)
    if bad.any():
        i, c = np.argwhere(bad)[0]
        raise DeviceProtocolError(f"values: sample {i} of {channels[c]} is {rows[i, c]!r}", "values")
    return rows


def _length(values: Any) -> int:
    try:
        return len(values)
    except TypeError:
        return 1  # a bare number: one sample


def check_rate(samples: int, rate_hz: float, since_start_s: float) -> None:
    """``samples`` read of the acquisition that started ``since_start_s`` ago (host clock)."""
    if lead_s(samples / rate_hz, since_start_s, LEAD_MARGIN_S) > 0:
        raise DeviceProtocolError(f"rate: {samples} samples in {since_start_s:.3f} s: the sample clock runs at "
                                  f"~{samples / max(since_start_s, 1e-3):.0f} Hz, driver.rate_hz is {rate_hz:g} "
                                  f"(allowed {MAX_CLOCK_ERROR:.0%} off)", "rate")
