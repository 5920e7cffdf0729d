"""The free-air rise as a characterisation keeps it (its crossings of fractions of the
equilibrium) and the free equilibrium of eq. 1: shared by the P-V fit (tasks/characterise.py)
and the ISO valve's fit (tasks/valve_rise.py), which read rig and model the same way."""

from __future__ import annotations

import numpy as np

RISE_FRACTIONS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)  # the rise kept per cycle: when it crossed these
RISE_SMOOTH_S = 0.011  # moving average before the crossings are taken (11 samples at 1 kHz)
RISE_MIN_LEVEL = 0.5  # rises fitted only at levels at least this fraction of the top one (clear of the noise)


def smooth_width(dt: float) -> int:
    """Samples in the moving average the rise's crossings are taken on (odd, at least 1)."""
    return max(1, int(round(RISE_SMOOTH_S / dt)) | 1)


def smoothed(q: np.ndarray, w: int) -> np.ndarray:
    return np.convolve(q, np.ones(w) / w, mode="same") if q.size > w else q


def rise_crossings(t: np.ndarray, qs: np.ndarray, level: float) -> list[float] | None:
    """The rise, kept compactly: when the trace (upwards, already averaged over
    RISE_SMOOTH_S) first crossed each of RISE_FRACTIONS of ``level`` (interpolated), or None
    when it missed one. On the averaged trace: the first crossing of a noisy trace comes
    early, the more so where the rise is slow (it biased the resistance 2-6 % low). The ISO
    valve's fit takes the simulated rise through this same function, so the averaging's
    own shift (large where the rise is fast beside the window) is in the model too."""
    times = []
    for f in RISE_FRACTIONS:
        i = np.flatnonzero(qs >= f * level)
        if not i.size or i[0] == 0:
            return None
        j = i[0]
        times.append(float(t[j - 1] + (f * level - qs[j - 1]) * (t[j] - t[j - 1]) / (qs[j] - qs[j - 1])))
    return times


def free_equilibrium(p0: np.ndarray | float, v_tank: float, v_act0: float, c: float, p_atm: float):
    """Gauge pressure (Pa) at which a tank of ``v_tank`` at gauge ``p0`` and an actuator side
    of volume ``v_act0 + c p`` (actuator, hose and ports, from atmosphere) settle: eq. 1,
    ``c Pe^2 + (Vt + V0 + c Pa) Pe - P0 Vt = 0``; the root that goes to P0 Vt / (Vt + V0)
    as c goes to zero (either sign of P0)."""
    b = v_tank + v_act0 + c * p_atm
    p0 = np.asarray(p0, dtype=float)
    disc = b * b + 4.0 * c * p0 * v_tank
    # the numerically stable form of (-b + sqrt(disc)) / (2c)
    return 2.0 * p0 * v_tank / (b + np.sqrt(disc))
