"""Readings that stood still inside a cycle's measured span: a box or a sensor that froze
for less than the supervisor's ``stuck_s`` (docs/safety.md, "A freeze shorter than
stuck_s").

The supervisor faults a pressure that has not changed for ``stuck_s`` (0.25 s). A
shorter freeze passes it, but its readings are not the sensor's: a Modbus box whose
inputs stood still for 0.2 s inside a measuring window moved that window's mean by
0.05 kPa with nothing to say so. A live sensor's readings are noisy: two in a row are
equal by chance (a sensor quantum against its noise); a box that refreshes its inputs
once per control cycle repeats one when a poll and a cycle drift past each other; a box
that stalls answers the polls that waited with one image (runs of up to 26 ms through
the emulated box on a loaded machine, ``python -m lab bench freeze``). A run of equal
readings for ``freeze_s`` (50 ms by default) is none of those: it marks the cycle's
reading unreliable, naming the channel, when and where (a window, the offset window, the
actuation whose dP gives the contact features)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from fluidsense.common.units import KPA


@dataclass(frozen=True)
class Frozen:
    """The longest run of equal readings that overlaps the measured span."""

    start: float  # sample time of the run's first reading
    held_s: float  # to its last reading
    value: float


def longest_run(t: np.ndarray, p: np.ndarray, lo: float, hi: float) -> Frozen | None:
    """The longest run of exactly equal consecutive readings of ``p`` that overlaps
    [``lo``, ``hi``); None for fewer than two samples. A run lasts from its first reading
    to its last: slots the sampler missed after a reading (no sample, docs/sampler.md) do
    not make it look held (they did, counted to the next changed reading: a plain measure
    through a loaded machine's box then showed 17-20 ms runs of one or two readings)."""
    if len(p) < 2:
        return None
    begins = np.flatnonzero(p[1:] != p[:-1]) + 1  # a new value starts (NaN never equals: each its own run)
    starts = np.concatenate(([0], begins))
    ends = t[np.concatenate((begins - 1, [len(p) - 1]))]
    held = ends - t[starts]
    inside = (t[starts] < hi) & (ends >= lo)
    if not inside.any():
        return None
    k = int(np.flatnonzero(inside)[np.argmax(held[inside])])
    return Frozen(float(t[starts[k]]), float(held[k]), float(p[starts[k]]))


def where(run: Frozen, t_open: float, offset_s: float, windows) -> str:
    """Which part of the measurement the run overlaps, in words."""
    a, b = run.start - t_open, run.start - t_open + run.held_s
    named = [w.name for w in windows if a < w.end_s and b > w.start_s]
    if named:
        return "window " + ", ".join(named)
    if a < 0 and b > -offset_s:
        return "the offset window"
    return "the actuation (dP and contact times)"


def reason(channel: str, run: Frozen, t_open: float, part: str, freeze_s: float) -> str:
    return (f"{channel} read {run.value / KPA:.3f} kPa unchanged for {run.held_s:.3f} s from "
            f"{run.start - t_open:+.3f} s after opening, in {part}: a box or sensor that froze (a live one "
            f"repeats a reading for a few ms; {freeze_s:g} s is supervision.freeze_s), so those readings are not "
            "the sensor's")
