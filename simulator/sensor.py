"""Sensor model: offset, slow drift, white noise, ADC quantisation, range (rails)."""

from __future__ import annotations

import numpy as np
from fluidsense.common.hardware import FlowSensor, Sensor
from fluidsense.common.units import KPA, SLPM


class SensorModel:
    """Works in SI: Pa for pressure sensors, standard m^3/s for flow sensors."""

    def __init__(self, lo: float, hi: float, offset: float, drift_per_s: float, noise_sd: float,
                 quantum: float, rng: np.random.Generator):
        self.lo, self.hi = lo, hi
        self.offset = offset
        self.drift_per_s = drift_per_s
        self.noise_sd = noise_sd
        self.quantum = quantum
        self.rng = rng
        self.gain = 1.0  # repeatability of reading, redrawn per cycle by the cell (simulator/budget.py)
        self.fault: str | None = None  # injected: "nan", "stuck", "rail"
        self.fault_from = float("inf")
        self._stuck_value: float | None = None

    @classmethod
    def pressure(cls, spec: Sensor, rng: np.random.Generator) -> SensorModel:
        return cls(spec.range_kpa[0] * KPA, spec.range_kpa[1] * KPA, spec.offset_kpa * KPA,
                   spec.drift_kpa_per_h * KPA / 3600.0, spec.noise_sd_kpa * KPA, spec.quantum_kpa * KPA, rng)

    @classmethod
    def flow(cls, spec: FlowSensor, rng: np.random.Generator) -> SensorModel:
        return cls(spec.range_slpm[0] * SLPM, spec.range_slpm[1] * SLPM, spec.offset_slpm * SLPM, 0.0,
                   spec.noise_sd_slpm * SLPM, spec.quantum_slpm * SLPM, rng)

    def read(self, t: np.ndarray, true: np.ndarray) -> np.ndarray:
        """What the sensor reports for the true values at times t."""
        out = true * self.gain + self.offset + self.drift_per_s * t
        if self.noise_sd > 0:
            out = out + self.rng.normal(0.0, self.noise_sd, size=out.shape)
        if self.quantum > 0:
            out = np.round(out / self.quantum) * self.quantum
        # a saturated sensor reports its rail; the supervisor treats the rail as a fault
        out = np.clip(out, self.lo, self.hi)
        if self.fault is not None:
            bad = t >= self.fault_from
            if bad.any():
                first = int(np.argmax(bad))
                if self.fault == "nan":
                    out[bad] = np.nan
                elif self.fault == "rail":
                    out[bad] = self.hi
                elif self.fault == "stuck":
                    if self._stuck_value is None:
                        self._stuck_value = float(out[first - 1]) if first > 0 else float(out[first])
                    out[bad] = self._stuck_value
        return out

    def inject(self, kind: str, t: float) -> None:
        self.fault, self.fault_from, self._stuck_value = kind, t, None
