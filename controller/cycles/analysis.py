"""One cycle's recorded trace and the features computed from it."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from fluidsense.common.samples import SampleBlock
from fluidsense.common.units import KPA
from fluidsense.controller.config import SequenceConfig
from fluidsense.controller.cycles import features as F
from fluidsense.controller.cycles import frozen
from fluidsense.controller.cycles.sequencer import Transition


class CycleTrace:
    """Collects the blocks of one cycle; ``arrays()`` joins them once at the end."""

    def __init__(self) -> None:
        self._t: list[np.ndarray] = []
        self._v: list[np.ndarray] = []
        self.channels: tuple[str, ...] = ()
        self.missed = 0

    def add(self, block: SampleBlock) -> None:
        self.channels = block.channels
        self._t.append(block.t)
        self._v.append(block.values)
        self.missed += block.missed

    def tail(self, seconds: float) -> tuple[np.ndarray, np.ndarray]:
        """The samples of the last ``seconds`` (at least), joined: cheap to ask often."""
        k = len(self._t)
        while k > 0 and self._t[-1][-1] - self._t[k - 1][0] < seconds:
            k -= 1
        k = max(k - 1, 0)
        if not self._t:
            return np.empty(0), np.empty((0, len(self.channels)))
        return np.concatenate(self._t[k:]), np.vstack(self._v[k:])

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        if not self._t:
            return np.empty(0), np.empty((0, len(self.channels)))
        return np.concatenate(self._t), np.vstack(self._v)


@dataclass(frozen=True)
class Reference:
    """Free-air reference: offset-corrected actuator pressure against time since opening."""

    t_rel: np.ndarray
    p: np.ndarray
    cycle_id: int


@dataclass
class WindowResult:
    name: str
    start_s: float
    end_s: float
    mean: float
    sd: float
    n: int

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "start_s": self.start_s, "end_s": self.end_s,
                "mean_kpa": _kpa(self.mean), "sd_kpa": _kpa(self.sd), "n": self.n}


@dataclass
class CycleResult:
    cycle_id: int
    p0: float
    t_start: float
    t_open: float | None
    t_end: float | None
    aborted: str | None = None
    label: str | None = None
    offset: float | None = None
    windows: list[WindowResult] = field(default_factory=list)
    is_reference: bool = False
    has_reference: bool = False
    dp_eq: float | None = None
    dp_max: float | None = None
    t_dp_max: float | None = None
    t_c_slope: float | None = None
    t_c_threshold: float | None = None
    t_c2: float | None = None
    t_c_onset: float | None = None  # the first rise of dP out of its noise
    rise_shift: float | None = None  # s this cycle rose later than the reference (sequence.align_rise_kpa)
    v_eq: float | None = None  # standard m^3 into the actuator over the flow window
    flow_offset: float | None = None
    samples: int = 0
    missed: int = 0
    unchanged_s: float | None = None  # longest run of unchanged p_act readings in the measured span
    unreliable: str | None = None  # why the reading is not to be trusted (a freeze under stuck_s), or None
    trace: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)

    @property
    def ok(self) -> bool:
        return self.aborted is None and bool(self.windows)

    @property
    def p_eq(self) -> float | None:
        return self.windows[0].mean if self.windows else None

    @property
    def p_sd(self) -> float | None:
        return self.windows[0].sd if self.windows else None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, kPa and seconds (times relative to the valve opening where named _s)."""
        return {
            "cycle_id": self.cycle_id, "label": self.label, "p0_kpa": _kpa(self.p0),
            "t_start_s": self.t_start, "t_open_s": self.t_open, "t_end_s": self.t_end,
            "aborted": self.aborted, "ok": self.ok,
            "offset_kpa": _kpa(self.offset), "p_eq_kpa": _kpa(self.p_eq), "p_sd_kpa": _kpa(self.p_sd),
            "windows": [w.to_dict() for w in self.windows],
            "is_reference": self.is_reference, "has_reference": self.has_reference,
            "dp_eq_kpa": _kpa(self.dp_eq), "dp_max_kpa": _kpa(self.dp_max), "t_dp_max_s": self.t_dp_max,
            "t_c_slope_s": self.t_c_slope, "t_c_threshold_s": self.t_c_threshold, "t_c2_s": self.t_c2,
            "t_c_onset_s": self.t_c_onset, "rise_shift_s": self.rise_shift,
            "v_eq_ml": None if self.v_eq is None else self.v_eq * 1e6,
            "samples": self.samples, "missed": self.missed,
            "unchanged_s": self.unchanged_s, "unreliable": self.unreliable,
        }


def _kpa(v: float | None) -> float | None:
    return None if v is None or not math.isfinite(v) else v / KPA


def analyse(cycle_id: int, p0: float, t_start: float, t_open: float | None, t_end: float | None,
            t: np.ndarray, values: np.ndarray, channels: tuple[str, ...], cfg: SequenceConfig,
            reference: Reference | None, aborted: str | None = None, label: str | None = None,
            missed: int = 0, freeze_s: float | None = None) -> CycleResult:
    """Features of one cycle from its recorded samples (SI units). ``freeze_s``: a run of
    unchanged p_act readings this long in the measured span makes the result unreliable
    (frozen.py); None: not looked for (a noise-free simulated sensor never changes)."""
    res = CycleResult(cycle_id, p0, t_start, t_open, t_end, aborted=aborted, label=label,
                      samples=len(t), missed=missed)
    if t_open is None or aborted is not None:
        return res
    p = values[:, channels.index("p_act")]
    res.offset = F.sensor_offset(t, p, t_open, cfg.offset_s)
    pc = p - res.offset
    for w in cfg.windows:
        ws = F.window_stats(t, pc, t_open, w.start_s, w.end_s)
        res.windows.append(WindowResult(w.name, w.start_s, w.end_s, ws.mean, ws.sd, ws.n))
    if freeze_s is not None:
        # the offset window, the windows and the actuation whose dP gives the contact times
        run = frozen.longest_run(t, p, t_open - cfg.offset_s, t_open + cfg.actuate_s)
        if run is not None:
            res.unchanged_s = run.held_s
            if run.held_s >= freeze_s:
                part = frozen.where(run, t_open, cfg.offset_s, cfg.windows)
                res.unreliable = frozen.reason("p_act", run, t_open, part, freeze_s)
    if cfg.flow_window is not None and "flow" in channels:
        q = values[:, channels.index("flow")]
        res.flow_offset = F.sensor_offset(t, q, t_open, cfg.offset_s)
        fw = cfg.flow_window
        res.v_eq = F.integrate(t, q - res.flow_offset, t_open + fw.start_s, t_open + fw.end_s)
    opened = (t >= t_open) & (t < t_open + cfg.actuate_s)
    t_rel, p_rel = t[opened] - t_open, pc[opened]
    res.trace = (t_rel, p_rel)
    if reference is None:
        return res
    res.has_reference = True
    # contact pushes the pressure away from atmosphere: for vacuum, flip so contact is +
    sign = -1.0 if p0 < 0 else 1.0
    t_al = t_rel  # time since opening, as the reference's opening was timed
    if cfg.align_rise_kpa is not None:
        lo, hi = (v * KPA for v in cfg.align_rise_kpa)
        res.rise_shift = F.rise_shift(t_rel, sign * p_rel, reference.t_rel, sign * reference.p, lo, hi)
        if res.rise_shift is not None:
            t_al = t_rel - res.rise_shift
    dp = F.delta_p(t_al, p_rel, reference.t_rel, reference.p)
    dps = _smooth_within(dp, cfg.smoothing_samples)
    oriented = sign * dps
    first = cfg.windows[0]
    in_first = (t_rel >= first.start_s) & (t_rel < first.end_s) & np.isfinite(dp)
    if in_first.any():
        res.dp_eq = float(np.mean(dp[in_first]))
    peak = F.dp_max(t_al, oriented)
    if peak is not None:
        res.dp_max, res.t_dp_max = sign * peak[0], peak[1]
    threshold = cfg.contact_threshold_kpa * KPA
    res.t_c_threshold = F.contact_time_threshold(t_al, oriented, threshold)
    res.t_c_onset = F.contact_time_threshold(t_al, oriented, cfg.onset_kpa * KPA)
    res.t_c_slope = F.contact_time_slope(t_al, oriented, min_rise=threshold)
    if res.t_c_slope is not None:
        res.t_c2 = F.second_contact_time(t_al, oriented, res.t_c_slope, min_rise=threshold)
    return res


def _smooth_within(dp: np.ndarray, span: int) -> np.ndarray:
    """dP smoothed over the span the reference covers: the samples outside it (NaN) are left
    out of the fit, not read as zeros, which at a held object's dP of a few kPa would bend
    the last span of the curve (an aligned cycle ends up to its shift after the reference)."""
    out = np.full_like(dp, np.nan)
    idx = np.flatnonzero(np.isfinite(dp))
    if len(idx):
        a, b = idx[0], idx[-1] + 1
        out[a:b] = F.smooth(np.nan_to_num(dp[a:b], nan=0.0), span)
        out[~np.isfinite(dp)] = np.nan
    return out


def make_reference(result: CycleResult) -> Reference:
    if result.trace is None:
        raise ValueError(f"cycle {result.cycle_id} has no trace to serve as reference")
    t_rel, p = result.trace
    return Reference(t_rel.copy(), p.copy(), result.cycle_id)


def transition_dict(tr: Transition) -> dict[str, Any]:
    return {"cycle_id": tr.cycle_id, "at_s": tr.t, "from": tr.source.value, "to": tr.target.value,
            "reason": tr.reason}
