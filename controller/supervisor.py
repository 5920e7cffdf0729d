"""Safety supervisor: checks every block before the sequencer sees it.

A finding is a ``Fault``; the controller answers any fault with the safe state (actuator
vented, tank isolated) and latches it until ``reset``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivers.base import SampleBlock

from .config import Profile

KPA = 1e3


@dataclass(frozen=True)
class Fault:
    kind: str  # over_pressure, under_pressure, sensor_nan, sensor_range, missed_samples
    channel: str | None
    t: float
    detail: str


class Supervisor:
    def __init__(self, profile: Profile):
        self.max_pa = profile.limits.max_pa
        self.min_pa = profile.limits.min_pa
        # a reading on a sensor's rail means it is saturated: the true value is unknown
        self.rails = {
            "p_act": (profile.sensor.range_kpa[0] * KPA, profile.sensor.range_kpa[1] * KPA),
            "p_tank": (profile.tank_sensor.range_kpa[0] * KPA, profile.tank_sensor.range_kpa[1] * KPA),
        }

    def check(self, block: SampleBlock) -> Fault | None:
        for j, ch in enumerate(block.channels):
            if not ch.startswith("p_"):
                continue
            v = block.values[:, j]
            bad = ~np.isfinite(v)
            if bad.any():
                k = int(np.argmax(bad))
                return Fault("sensor_nan", ch, float(block.t[k]), f"{ch} reads NaN")
            lo, hi = self.rails.get(ch, (-np.inf, np.inf))
            rail = (v <= lo) | (v >= hi)
            if rail.any():
                k = int(np.argmax(rail))
                return Fault("sensor_range", ch, float(block.t[k]),
                             f"{ch} at its range limit ({v[k] / KPA:.2f} kPa)")
            over = v > self.max_pa
            if over.any():
                k = int(np.argmax(over))
                return Fault("over_pressure", ch, float(block.t[k]),
                             f"{ch} {v[k] / KPA:.2f} kPa above the limit {self.max_pa / KPA:.2f} kPa")
            under = v < self.min_pa
            if under.any():
                k = int(np.argmax(under))
                return Fault("under_pressure", ch, float(block.t[k]),
                             f"{ch} {v[k] / KPA:.2f} kPa below the limit {self.min_pa / KPA:.2f} kPa")
        return None
