"""Pressure sensor model: offset, slow drift, white noise, ADC quantisation, range."""

from __future__ import annotations

import numpy as np

from ..hardware import Sensor
from ..units import KPA


class SensorModel:
    def __init__(self, spec: Sensor, rng: np.random.Generator):
        self.spec = spec
        self.rng = rng
        self.lo = spec.range_kpa[0] * KPA
        self.hi = spec.range_kpa[1] * KPA
        self.offset = spec.offset_kpa * KPA
        self.drift_per_s = spec.drift_kpa_per_h * KPA / 3600.0
        self.noise_sd = spec.noise_sd_kpa * KPA
        self.quantum = spec.quantum_kpa * KPA

    def read(self, t: np.ndarray, p_gauge: np.ndarray) -> np.ndarray:
        """What the sensor reports (Pa) for true gauge pressures at times t."""
        out = p_gauge + self.offset + self.drift_per_s * t
        if self.noise_sd > 0:
            out = out + self.rng.normal(0.0, self.noise_sd, size=out.shape)
        if self.quantum > 0:
            out = np.round(out / self.quantum) * self.quantum
        # a saturated sensor reports its rail; the supervisor treats the rail as a fault
        return np.clip(out, self.lo, self.hi)
