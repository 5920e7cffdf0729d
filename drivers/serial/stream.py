"""The serial device's sample frames, from the wire to sample blocks: what a frame may say
(``SessionGuard``) and how accepted frames become blocks (``Blocks``).

Every field of a frame that passed its CRC is still the device's word, and a device can
be wrong (a firmware built for another board, a counter that jumps, a timer at the wrong
rate) or hostile. What it cannot have said is one DeviceProtocolError naming the field,
and the link is dropped and connected again (a new session, ticks from 0):

- ``counts``: as many counts as inputs in the session's ADC mask, each within the ADC's
  bits;
- ``tick``: a tick jump the host clock cannot account for (the session's first tick
  included: a session starts at tick 0);
- ``rate``: ticks that run ahead of the host clock since the session's first sample by
  more than the clock's tolerance (MAX_CLOCK_ERROR) and LEAD_MARGIN_S: a timer faster
  than ``rate_hz``. A sample cannot arrive before it is taken, so however late the host
  reads (a loaded machine, a stalled thread), ticks never lead the host clock; only a
  first sample read late (by up to LEAD_MARGIN_S) makes the later ones look early;
- ``seq``: more frames missing between two sample frames than the device can have sent
  in between (one per tick, plus the acknowledgements of the commands sent meanwhile).
"""

from __future__ import annotations

import numpy as np
from fluidsense.common.errors import DeviceProtocolError, DriverError
from fluidsense.common.samples import SampleBlock

from ..clockcheck import MAX_CLOCK_ERROR, lead_s
from . import protocol as p
from .clock import Timeline
from .config import SerialDriverConfig

LATE_S = 50e-6  # a sample converted this long after its tick is late (as the sampler process counts it)
#: how late the host may read the frame a bound starts from (the reader thread scheduled
#: late on a loaded machine); the session's first tick may also follow START's acknowledgement
#: by every retry of START
LEAD_MARGIN_S = 0.25
#: frames beside samples and acknowledgements that a session may lose (none are sent today)
SEQ_SLACK = 4


class DeviceResetError(DriverError):
    """The device restarted: its session, outputs and ticks are gone."""


class SessionGuard:
    """The checks of one session's sample frames, from START's acknowledgement on."""

    def __init__(self, cfg: SerialDriverConfig, n_channels: int, started: float):
        """``started``: the host time (time.monotonic) START's acknowledgement arrived."""
        self.rate_hz = float(cfg.rate_hz)
        self.n_channels = n_channels
        self.bits = cfg.adc.bits
        self.first_lead_s = cfg.ack_timeout_s * (cfg.retries + 1) + LEAD_MARGIN_S
        self._tick = -1  # the last sample's tick: the first one is 0
        self._arrival = started
        self._first: tuple[int, float] | None = None  # the session's first sample: tick, arrival
        self._commands = 0

    def check(self, f: p.Sample, tick: int, arrival: float, lost: int, commands: int) -> DeviceProtocolError | None:
        """``tick``: the frame's tick, unwrapped; ``lost``: frames missing (gaps in ``seq``)
        since the last sample frame; ``commands``: commands sent so far (retries included).
        The error this frame is, or None."""
        if len(f.counts) != self.n_channels:
            return DeviceProtocolError(f"counts: {len(f.counts)} channel counts in a sample frame, "
                                       f"{self.n_channels} in the session's ADC mask", "counts")
        top = (1 << self.bits) - 1
        if f.counts and max(f.counts) > top:
            return DeviceProtocolError(f"counts: a count of {max(f.counts)} from a {self.bits}-bit ADC "
                                       f"(at most {top}): driver.adc.bits, or not this firmware", "counts")
        step, dt = tick - self._tick, arrival - self._arrival
        lead = LEAD_MARGIN_S if self._first is not None else self.first_lead_s
        if lead_s((step - 1) / self.rate_hz, dt, lead) > 0:
            return DeviceProtocolError(f"tick: tick {tick} after {self._tick}: {step - 1} samples skipped "
                                       f"({(step - 1) / self.rate_hz:.6g} s at {self.rate_hz:g} Hz) within "
                                       f"{dt:.3f} s", "tick")
        if self._first is None:
            self._first = (tick, arrival)
        ticks, since = tick - self._first[0], arrival - self._first[1]
        if lead_s(ticks / self.rate_hz, since, LEAD_MARGIN_S) > 0:
            return DeviceProtocolError(f"rate: {ticks} ticks in {since:.3f} s: the device's timer runs at "
                                       f"~{ticks / max(since, 1e-3):.0f} Hz, driver.rate_hz is {self.rate_hz:g} "
                                       f"(allowed {MAX_CLOCK_ERROR:.0%} off)", "rate")
        possible = (step - 1) + (commands - self._commands) + SEQ_SLACK
        if lost > possible:
            return DeviceProtocolError(f"seq: {lost} frames missing between ticks {self._tick} and {tick}, where "
                                       f"at most {possible} can have been sent", "seq")
        self._tick, self._arrival, self._commands = tick, arrival, commands
        return None


class Blocks:
    """Accepted samples -> SampleBlocks of ``block_size``, in channel order and Pa."""

    def __init__(self, timeline: Timeline, channels: tuple[str, ...], order: np.ndarray, gain: np.ndarray,
                 offset: np.ndarray, block_size: int):
        self.timeline, self.channels = timeline, channels
        # the device's columns (lowest input first) in channel order, then Pa = gain * count + offset
        self._order, self._gain, self._offset = order, gain, offset
        self.block_size = block_size
        self._ks: list[int] = []
        self._rows: list[tuple[int, ...]] = []
        self._late: list[int] = []

    def add(self, k: int, f: p.Sample) -> SampleBlock | None:
        """Slot ``k``'s sample; a block when one is full."""
        self._ks.append(k)
        self._rows.append(f.counts)
        self._late.append(f.late_us)
        return self._emit() if len(self._ks) >= self.block_size else None

    def _emit(self) -> SampleBlock:
        ks = np.array(self._ks)
        late = np.array(self._late, dtype=float) * 1e-6
        values = np.array(self._rows, dtype=float)[:, self._order] * self._gain + self._offset
        missed = int(ks[-1] - self.timeline.k_delivered) - len(ks)
        self.timeline.k_delivered = int(ks[-1])
        self._ks, self._rows, self._late = [], [], []
        return SampleBlock(0, ks / self.timeline.rate_hz + late, values, self.channels, missed=missed,
                           late=int(np.count_nonzero(late > LATE_S)), lateness_s=late)
