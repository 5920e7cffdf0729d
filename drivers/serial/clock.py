"""One sample clock across the device's sessions, and the host's view of it.

Sample time is the device's: sample k is at ``k / rate_hz`` (its timer's ticks), plus
the few microseconds by which the device reports it started the conversion late. The
host clock only aligns: ``origin`` is the CLOCK_MONOTONIC time of sample time 0, from
the lower envelope of ``arrival - t`` (a sample cannot arrive before it is taken; the
fastest arrivals carry only the link's fixed delay). The minima of one-second buckets
are fitted by a line, whose slope is the device clock's drift against the host's (a
crystal: tens of ppm; a ceramic resonator: up to 0.5 %), so ``origin`` follows it.

A new session (a reconnection, a device reset) restarts the device's ticks at 0; its
first sample is placed on the slot the host clock says it belongs to (never before the
last one delivered), and the slots in between are missed.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

BUCKET_S = 1.0
BUCKETS = 30


class Timeline:
    def __init__(self, rate_hz: float):
        self.rate_hz = float(rate_hz)
        self.k_delivered = -1  # the last slot delivered in a block
        self.k_last = -1  # the last slot seen (delivered or not)
        self.origin: float | None = None
        self.drift_ppm = 0.0
        self._base: int | None = None  # slot of the session's tick 0
        self._minima: deque[tuple[float, float]] = deque(maxlen=BUCKETS)
        self._bucket_end = -math.inf
        self._bucket_min = math.inf
        self._bucket_at = 0.0  # the arrival of the bucket's minimum
        self._fit: tuple[float, float] | None = None  # origin = a + b * arrival

    def new_session(self) -> None:
        self._base = None

    def slot(self, tick: int, arrival: float) -> int:
        """The slot of the session's tick ``tick`` (ticks grow within a session)."""
        if self._base is None:
            if self.origin is None:
                self._base = -tick
            else:
                guess = math.floor((arrival - self.origin) * self.rate_hz)
                self._base = max(self.k_last + 1, guess) - tick
        k = self._base + tick
        self.k_last = k
        self._track(k / self.rate_hz, arrival)
        return k

    def _track(self, t: float, arrival: float) -> None:
        offset = arrival - t
        if self.origin is None:
            self.origin = offset
        if arrival >= self._bucket_end:
            if math.isfinite(self._bucket_min):
                self._minima.append((self._bucket_at, self._bucket_min))
                self._refit()
            self._bucket_end, self._bucket_min, self._bucket_at = arrival + BUCKET_S, offset, arrival
        elif offset < self._bucket_min:
            self._bucket_min, self._bucket_at = offset, arrival
        if self._fit is not None:
            a, b = self._fit
            self.origin = a + b * arrival
        # a sample never arrives before it is taken: an origin later than an arrival says so
        if offset < self.origin:
            self.origin = offset

    def _refit(self) -> None:
        if len(self._minima) < 3:
            self._fit = None
            return
        x, y = np.array(self._minima).T
        b, a = np.polyfit(x - x[0], y, 1)
        self._fit = (a - b * x[0], b)
        self.drift_ppm = float(b * 1e6)

    def stats(self) -> dict[str, float | None]:
        return {"clock_origin_s": self.origin, "drift_ppm": self.drift_ppm}
