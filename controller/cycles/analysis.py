"""One cycle's recorded trace and the features computed from it."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from fluidsense.common.hardware import Circuit
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


def reference_key(p0_pa: float) -> float:
    """The key a free-air reference is kept and found under: its P0 in kPa, to the Pa
    (every store and look-up of references uses this one function)."""
    return round(p0_pa / KPA, 3)


#: 'auto' alignment levels, as fractions of the reference's level in the first window: low
#: enough to be over before a gripper's fingers reach anything they can hold (the sorting
#: gripper's 100 mm cylinder is met at 60 % of the level, the quick PneuNet's at 20 %), high
#: enough to be many times the noise
AUTO_RISE = (0.02, 0.08)
#: ... and at least this many times the reference's noise in the first window
AUTO_RISE_NOISE = (5.0, 10.0)
#: ... and the upper level at least this many sample periods after the lower one on the
#: reference: a steep rise sampled at 500 Hz crosses 2-8 % in two samples, and a polled
#: driver's one late or missing sample there would leave nothing to align on
AUTO_RISE_SAMPLES = 8
#: the levels stay on the first part of the rise: past this fraction of the level the
#: curve bends over, and fingers begin to reach the largest objects
AUTO_RISE_MAX = 0.3
#: levels between lo and hi whose crossing times are compared, and how many must be
#: clear of gaps in the samples
RISE_LEVELS, RISE_MIN_LEVELS = 7, 3
#: a grasp's object needs its equilibrium dP beyond this many sd of the difference of two
#: free-air cycles (one in about 30,000 empty grips for a normal cycle-to-cycle error)
OBJECT_SIGMAS = 4.0


@dataclass(frozen=True)
class Alignment:
    """How a cycle is lined up with its reference: the rise's levels (Pa, oriented: the
    rise upwards), and ``t_min`` (s after the reference's opening), before which dP says
    nothing about contact: the reference has passed the upper level, and rises slowly enough
    there that a sample period of timing is worth at most half the contact threshold."""

    lo: float
    hi: float
    t_min: float


def alignment(cfg: SequenceConfig, reference: Reference, sign: float) -> Alignment | None:
    """The rise's levels for ``reference`` (``cfg.align_rise_kpa``), or None where the
    cycles keep their commanded timing (``align_rise_kpa: null``, or an 'auto' reference whose
    rise is too small to align on)."""
    spec = cfg.align_rise_kpa
    if spec is None:
        return None
    ref = sign * reference.p
    if spec == "auto":
        first = cfg.windows[0]
        sel = (reference.t_rel >= first.start_s) & (reference.t_rel < first.end_s)
        if sel.sum() < 2:
            return None
        level, noise = float(np.mean(ref[sel])), float(np.std(ref[sel]))
        lo = max(AUTO_RISE[0] * level, AUTO_RISE_NOISE[0] * noise)
        hi = max(AUTO_RISE[1] * level, AUTO_RISE_NOISE[1] * noise)
        if not 0 < lo < hi <= AUTO_RISE_MAX * level:  # a rise too small for its noise
            return None
        t_lo = F.crossing_time(reference.t_rel, ref, lo)
        if t_lo is not None and len(reference.t_rel) > 1:
            period = F.sample_period(reference.t_rel)
            hi = max(hi, float(np.interp(t_lo + AUTO_RISE_SAMPLES * period, reference.t_rel, ref)))
        hi = min(hi, AUTO_RISE_MAX * level)
    else:
        lo, hi = (v * KPA for v in spec)
    t_hi = F.crossing_time(reference.t_rel, ref, hi)
    if t_hi is None:
        return None
    return Alignment(lo, hi, _trusted_from(reference, ref, t_hi, cfg.contact_threshold_kpa * KPA,
                                           cfg.windows[0].start_s))


def _trusted_from(reference: Reference, ref: np.ndarray, t_hi: float, threshold: float,
                  first_window_s: float) -> float:
    """When dP first says something about contact: past the alignment's upper level, and
    where the reference rises slowly enough that a timing error of one sample period (a
    polled sample's place in its slot, which no alignment removes: seen through the emulated
    box at 500 Hz as a 0.3 kPa "contact" 41-53 ms after opening on free air) is worth at most
    half the contact threshold."""
    t, n = reference.t_rel, len(reference.t_rel)
    if n < 3:
        return t_hi
    period = F.sample_period(t)
    slope = np.gradient(F.smooth(ref, 21), t)
    # after the last steep sample before the first window, not the first calm one: a
    # reference read through a polled box has stalls whose smoothed slope dips on the rise
    hot = (t >= t_hi) & (t < first_window_s) & (np.abs(slope) * period > threshold / 2)
    if not hot.any():
        return t_hi
    k = int(np.flatnonzero(hot)[-1]) + 1
    return float(t[min(k, n - 1)])


def eq_sd(cfg: SequenceConfig, circuit: Circuit | None, level: float, p0: float) -> float:
    """Pa: the free-air equilibrium's sd from one cycle to the next (``cfg.eq_sd_kpa``, or the
    circuit's repeatability carried to ``level``, the free-air equilibrium at charge ``p0``,
    both gauge)."""
    if cfg.eq_sd_kpa is not None:
        return cfg.eq_sd_kpa * KPA
    if circuit is None:
        return 0.0
    if hasattr(circuit, "regulator_repeatability_kpa"):
        # tank: dP_eq/dP0 of eq. 1, about P_eq/P0 (the sorting gripper's 0.53 against the
        # 0.51 that its compliance gives); a regulated actuator sits at P0 (gain 1)
        gain = min(1.0, abs(level / p0)) if p0 else 1.0
        return circuit.regulator_repeatability_kpa * KPA * gain
    # flow: a fixed amount of gas, off by the controller's repeatability, at most that part
    # of the absolute pressure
    return getattr(circuit, "flow_repeatability", 0.0) * (abs(level) + circuit.p_atm)


def object_bound(cfg: SequenceConfig, circuit: Circuit | None = None, level: float = 0.0, p0: float = 0.0) -> float:
    """Pa: the equilibrium dP that tells an object from the free-air level's own spread."""
    return OBJECT_SIGMAS * math.sqrt(2.0) * eq_sd(cfg, circuit, level, p0)


def judge_object(res: CycleResult) -> tuple[bool | None, str | None]:
    """Object or not from the evidence that must agree: the equilibrium dP clear of its
    spread (``res.object_bound``), and the contact time. (None, why) where they disagree or
    cannot be had."""
    sign = -1.0 if res.p0 < 0 else 1.0
    if not res.has_reference:
        return None, "no free-air reference at this P0"
    if res.dp_eq is None or res.object_bound is None:
        return None, "no equilibrium dP (the first window is outside the reference)"
    if res.unreliable:  # a frozen input in the measured span: the readings are not the cell's
        return None, f"the reading is unreliable: {res.unreliable}"
    bound, eq = res.object_bound, sign * res.dp_eq
    if eq < -bound:
        return None, (f"the equilibrium is {-eq / KPA:.3f} kPa below the free-air reference, beyond its spread "
                      f"({bound / KPA:.3f} kPa): the reference does not fit this cycle (take a new one)")
    if eq > bound:
        return True, None
    if res.t_c_threshold is not None:
        return None, (f"contact at {res.t_c_threshold:.3f} s but the equilibrium dP ({res.dp_eq / KPA:+.3f} kPa) "
                      f"is within the free-air spread ({bound / KPA:.3f} kPa): the features disagree")
    return False, None


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
    t_c_min: float | None = None  # no contact time before this (the reference passes the alignment's upper level)
    object_bound: float | None = None  # |dP_eq| beyond this is an object (object_bound)
    object: bool | None = None  # judge_object: the equilibrium and the contact time agree
    object_note: str | None = None  # why object is None (or what else a reader must know)
    v_eq: float | None = None  # standard m^3 into the actuator over the flow window
    flow_offset: float | None = None
    samples: int = 0
    missed: int = 0
    unchanged_s: float | None = None  # longest run of unchanged p_act readings in the measured span
    unreliable: str | None = None  # why the reading is not to be trusted (a freeze under stuck_s), or None
    trace: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)
    # (s since opening, standard m^3/s offset removed) over the actuation, with a flow window:
    # characterise reads the sensor's peak (saturation) and the settled flow (a leak) from it
    flow_trace: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)

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
            "t_c_onset_s": self.t_c_onset, "rise_shift_s": self.rise_shift, "t_c_min_s": self.t_c_min,
            "object": self.object, "object_note": self.object_note, "object_bound_kpa": _kpa(self.object_bound),
            "v_eq_ml": None if self.v_eq is None else self.v_eq * 1e6,
            "samples": self.samples, "missed": self.missed,
            "unchanged_s": self.unchanged_s, "unreliable": self.unreliable,
        }


def _kpa(v: float | None) -> float | None:
    return None if v is None or not math.isfinite(v) else v / KPA


def analyse(cycle_id: int, p0: float, t_start: float, t_open: float | None, t_end: float | None,
            t: np.ndarray, values: np.ndarray, channels: tuple[str, ...], cfg: SequenceConfig,
            reference: Reference | None, aborted: str | None = None, label: str | None = None,
            missed: int = 0, circuit: Circuit | None = None, freeze_s: float | None = None) -> CycleResult:
    """Features of one cycle from its recorded samples (SI units). ``circuit``: the
    profile's, whose repeatability sets the object's bound (eq_sd). ``freeze_s``: a run of
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
    if res.flow_offset is not None:
        res.flow_trace = (t_rel, values[opened, channels.index("flow")] - res.flow_offset)
    if reference is None:
        return res
    res.has_reference = True
    # contact pushes the pressure away from atmosphere: for vacuum, flip so contact is +
    sign = -1.0 if p0 < 0 else 1.0
    t_al = t_rel  # time since opening, as the reference's opening was timed
    align = alignment(cfg, reference, sign)
    if align is not None:
        res.t_c_min = align.t_min
        res.rise_shift = F.rise_shift(t_rel, sign * p_rel, reference.t_rel, sign * reference.p, align.lo, align.hi,
                                      RISE_LEVELS, RISE_MIN_LEVELS)
        if res.rise_shift is not None:
            t_al = t_rel - res.rise_shift
    dp = F.delta_p(t_al, p_rel, reference.t_rel, reference.p)
    dps = _smooth_within(dp, cfg.smoothing_samples)
    oriented = sign * dps
    first = cfg.windows[0]
    in_first = (t_rel >= first.start_s) & (t_rel < first.end_s) & np.isfinite(dp)
    if in_first.any():
        res.dp_eq = float(np.mean(dp[in_first]))
    ref_first = (reference.t_rel >= first.start_s) & (reference.t_rel < first.end_s)
    if ref_first.any():
        res.object_bound = object_bound(cfg, circuit, float(np.mean(reference.p[ref_first])), p0)
    if align is not None:
        if res.rise_shift is None:
            # the rise could not be lined up (it never reached the levels, or samples are
            # missing across them): dP on the way up is the valve's timing, not contact
            res.object, res.object_note = judge_object(res)
            res.object_note = "; ".join(filter(None, [res.object_note, "the rise could not be aligned with the "
                                                      "reference's: no contact time"]))
            return res
        # before the reference has risen through the levels nothing can be told from dP:
        # a contact there is the alignment's residue, not a finger meeting something
        oriented = np.where(t_al >= align.t_min, oriented, np.nan)
    peak = F.dp_max(t_al, oriented)
    if peak is not None:
        res.dp_max, res.t_dp_max = sign * peak[0], peak[1]
    threshold = cfg.contact_threshold_kpa * KPA
    res.t_c_threshold = F.contact_time_threshold(t_al, oriented, threshold)
    res.t_c_onset = F.contact_time_threshold(t_al, oriented, cfg.onset_kpa * KPA)
    res.t_c_slope = F.contact_time_slope(t_al, oriented, min_rise=threshold)
    if res.t_c_slope is not None:
        res.t_c2 = F.second_contact_time(t_al, oriented, res.t_c_slope, min_rise=threshold)
    res.object, res.object_note = judge_object(res)
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
