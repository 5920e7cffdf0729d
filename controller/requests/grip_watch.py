"""What the gripper watches in the samples of a grip, block by block (pure: arrays in,
findings out, in sample time and Pa).

ContactWatch: the first contact during actuation, live. The actuator pressure (offset
removed, as the cycle's analysis does) is compared with the free-air reference at the
same time after opening; contact is a block whose mean dP is beyond the profile's contact
threshold, at the first sample of that block beyond it. With ``align`` (the profile's
``align_rise_kpa``, resolved for the reference: analysis.alignment) the samples wait until
the rise has passed its upper level, and are then compared on the reference's timing, as
the cycle's analysis does, and never before the reference has passed that level. The cycle's own
analysis gives the precise t_c afterwards (in ``grasp``); this one is for reacting while
it happens.

SlipWatch: while held, an abrupt fall of the pressure towards atmosphere (the object
moved out of the grip and the fingers closed further). A fall of ``drop_pa`` within
``within_s`` is a slip (a leak is a slow decay, which the supervisor faults on); it is
reported once the pressure has settled again (steady over half of ``within_s`` of
samples without a gap), with the settled level, so that a size can be estimated from it
and one slip is one report.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from fluidsense.controller.cycles import features as F
from fluidsense.controller.cycles.analysis import RISE_LEVELS, RISE_MIN_LEVELS, Alignment, Reference


class ContactWatch:
    def __init__(self, reference: Reference | None, threshold_pa: float, sign: float, offset_s: float,
                 until_s: float, align: Alignment | None = None):
        """``sign``: +1 when contact pushes the pressure up (inflation), -1 for vacuum;
        ``until_s``: stop looking this long after opening (the last measurement window);
        ``align``: the rise's levels (Pa, oriented) to line up with the reference's."""
        self.reference, self.threshold, self.sign = reference, threshold_pa, sign
        self.offset_s, self.until_s, self.align = offset_s, until_s, align
        self.t_min = align.t_min if align is not None else float("-inf")
        self._before: deque[tuple[np.ndarray, np.ndarray]] = deque()
        self._rising: list[tuple[np.ndarray, np.ndarray]] = []  # after opening, until the shift is known
        self.offset: float | None = None
        self.shift: float | None = None if align is not None else 0.0
        self.t_c: float | None = None
        self.done = reference is None

    def feed(self, t: np.ndarray, p: np.ndarray, t_open: float | None) -> float | None:
        """The block's samples; returns t_c (s after opening) the first time contact shows."""
        if self.done:
            return None
        if t_open is None or t[-1] < t_open:
            self._before.append((t, p))
            while len(self._before) > 1 and self._before[1][0][0] < t[-1] - self.offset_s - 0.05:
                self._before.popleft()
            return None
        if self.offset is None:
            self._before.append((t, p))
            tb = np.concatenate([b[0] for b in self._before])
            pb = np.concatenate([b[1] for b in self._before])
            self._before.clear()
            try:
                self.offset = F.sensor_offset(tb, pb, t_open, self.offset_s)
            except ValueError:  # no samples before opening: nothing to measure against
                self.done = True
                return None
        ref = self.reference
        t_rel = t - t_open
        if t_rel[0] > self.until_s:
            self.done = True
            return None
        if self.shift is None:
            t_rel, p = self._aligned(t_rel, p)
            if t_rel is None:
                return None
        t_al = t_rel - self.shift
        keep = (t_rel >= 0) & (t_rel <= self.until_s) & (t_al >= max(ref.t_rel[0], self.t_min)) \
            & (t_al <= ref.t_rel[-1])
        if not keep.any():
            return None
        dp = self.sign * (p[keep] - self.offset - np.interp(t_al[keep], ref.t_rel, ref.p))
        if float(np.mean(dp)) <= self.threshold:
            return None
        self.t_c = float(t_al[keep][int(np.argmax(dp > self.threshold))])
        self.done = True
        return self.t_c

    def _aligned(self, t_rel: np.ndarray, p: np.ndarray) -> tuple[np.ndarray | None, np.ndarray]:
        """Holds the samples until the rise has passed the upper level, then sets the shift
        and returns every held sample; (None, p) while still waiting."""
        self._rising.append((t_rel, p))
        t_all = np.concatenate([b[0] for b in self._rising])
        p_all = np.concatenate([b[1] for b in self._rising])
        after = t_all >= 0
        if not (self.sign * (p_all[after] - self.offset) >= self.align.hi).any():
            return None, p
        ref = self.reference
        shift = F.rise_shift(t_all[after], self.sign * (p_all[after] - self.offset), ref.t_rel, self.sign * ref.p,
                             self.align.lo, self.align.hi, RISE_LEVELS, RISE_MIN_LEVELS)
        if shift is None:
            # not lined up (samples missing across the levels): dP on the rise would be the
            # valve's timing, so nothing is reported live; the grasp says why
            self.done = True
            return None, p
        self.shift = shift
        self._rising.clear()
        return t_all, p_all


MIN_GAP_S = 0.05  # blocks come every 10 ms (10 samples at 1 kHz); 50 ms without one is a gap


class SlipWatch:
    def __init__(self, drop_pa: float, within_s: float, sign: float, level_pa: float):
        """``level_pa``: the held pressure when the grip settled (raw, as the samples read)."""
        self.drop, self.within, self.sign = drop_pa, within_s, sign
        self.level = sign * level_pa  # oriented: contact pushes it up
        self._hist: deque[tuple[float, float]] = deque()  # (t, oriented block mean)
        self._fall: tuple[float, float] | None = None  # (detected at, level before)
        self.gap = max(MIN_GAP_S, 0.2 * within_s)

    def feed(self, t: float, p: float) -> dict[str, float] | None:
        """A block's mean time and pressure (Pa); a settled slip as ``{at_s, drop_pa,
        level_pa}`` (level: the raw pressure it settled at)."""
        if self._hist and t - self._hist[-1][0] > self.gap:
            # samples missing (a stalled stream on a busy PC, whose backlog then arrives
            # later, stamped later): what the pressure did meanwhile is unknown, so no
            # steady stretch may span the gap. Spanning it, the bottom of the dip after a
            # slip once passed for the settled level.
            self._hist.clear()
        self._hist.append((t, self.sign * p))
        while self._hist and self._hist[-1][0] - self._hist[0][0] > self.within:
            self._hist.popleft()
        span = self._hist[-1][0] - self._hist[0][0]
        values = np.array([v for _, v in self._hist])
        recent = float(values[-3:].mean())  # a few blocks: a level, not a noisy sample
        # steady: no trend, the window's later half level with its earlier half. (The range
        # of the block means, used before, grows with their number and their noise: with
        # the sensor's noise it was rarely below drop / 3, and a slip waited for the
        # 10 x within_s fallback.)
        half = len(values) // 2
        steady = len(values) >= 6 and abs(float(values[half:].mean() - values[:half].mean())) < self.drop / 6
        if self._fall is None:
            if len(values) >= 3 and self.level - recent > self.drop:
                self._fall = (self._hist[-3][0] if len(values) >= 3 else t, self.level)
                self._hist = deque(list(self._hist)[-1:])
            elif span >= 0.9 * self.within and steady:  # follow slow drift (a leak is the supervisor's)
                self.level = float(values.mean())
            return None
        if not (span >= 0.5 * self.within and steady) and t - self._fall[0] < 10 * self.within:
            return None
        at, before = self._fall
        level = float(values[half:].mean()) if steady else recent
        self.level, self._fall = level, None
        self._hist.clear()
        return {"at_s": at, "drop_pa": before - level, "level_pa": self.sign * level}
