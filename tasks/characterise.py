"""Characterise an actuator on its rig: free-air cycles over a sweep of P0 (the tank
circuit: the tank's charge; the pressure-flow circuit: the regulated pressure, with the
flow into the actuator integrated), and from them the numbers a profile needs that the
rig can show.

What the readings can tell apart (docs/cli.md, "characterise"):
- The free-air equilibria fix the actuator's free P-V law (``v = v0 + c p``) through eq. 1
  (isothermal ideal gas; tank, hose and actuator start at the tank's P0 and at atmosphere):
  ``(P0 - Pe) Vt = Pe (v0 + Vh) + Pe (Pe + Pa) c`` in gauge pressures. Only ratios of
  volumes show in it: scale the tank, the hose and the actuator together and every
  equilibrium stays. The scale is the tank's volume the config states (``circuit.tank_l``,
  on its label) and the hose's bore and length: v0 and c are in units of them, and move with
  them if they are wrong.
- The pressure-flow circuit (method 2): the regulator holds the actuator at P0 and the flow
  sensor integrates what went in, V_eq (standard volume). Isothermal, from atmosphere:
  ``V_eq p_std = Pe (v0 + Vh) + c Pe (Pe + Pa)``, linear in (v0, c) and in ABSOLUTE volume:
  the flow sensor sets the scale (its calibration and its standard conditions: p_std is
  taken as the circuit's p_atm at the gas's temperature, as eq. 3 and the simulator take
  it; a sensor referenced elsewhere, or reading k times the true flow, scales v0 and c
  with it). Each cycle's own Pe (measured) is its abscissa, so the regulator's landing
  error is in the model, not the spread. A reading at the sensor's rail is refused (the
  integral loses what it cut); the leak is the flow still going in once settled (the
  regulator holds the pressure, so no drift shows).
- The cycle-to-cycle spread of the equilibrium at one P0 (``sequence.eq_sd_kpa``), the
  sensor's noise (the settled window's sd), the lag (where the rise starts), the settling
  time and the leak (the drift after settling) are read from the traces.
- The valve's conductance: for a laminar circuit without a hose (valve and resistor in
  series, no ISO 6358 valve), the path's resistance from the rise (an isothermal two-volume
  model with the fitted volumes, least squares on each trace). The rig shows only the sum of
  the valve and the resistor: the valve's assumed figure is kept and the resistor takes the
  rest. A tank circuit with an ISO 6358 valve: its sonic conductance C and the delay from
  the rise against the simulated plant's own network of the circuit (tasks/valve_rise.py),
  its critical ratio kept (the rise cannot separate it from C). Other circuits keep theirs
  (said so).

The fit is refused, naming why, when it cannot hold: fewer than three levels or two cycles
per level, a leak, a window that reads before the actuator settled, a residual beyond the
cycles' own spread (lack-of-fit test), a non-physical volume, a flow sensor at its rail, an
ISO valve's rise far beyond the sensor's noise from its model.
The flow-control circuit (method 3) is refused before any valve moves: its sweep is of a
flow programme, not of a pressure, and is not built here.
"""

from __future__ import annotations

import asyncio
import datetime
import math
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from fluidsense.common.errors import ConfigError, FluidsenseError, JobStopped
from fluidsense.common.hardware import PORT_VOLUME_M3
from fluidsense.common.scenes import EmptyScene
from fluidsense.common.units import KPA, LITRE, ML, SLPM
from fluidsense.controller.config.profile import FittedNumber, Profile, Provenance
from fluidsense.controller.ports import TaskPort
from scipy import integrate, optimize, stats

from .journal import CycleJournal
from .rise_trace import (
    RISE_FRACTIONS,
    RISE_MIN_LEVEL,
    free_equilibrium,
    rise_crossings,
    smooth_width,
    smoothed,
)
from .stopping import fault_dict, stopped_message
from .valve_rise import fit_iso_valve

Place = Callable[[Any], Awaitable[None]]

MIN_LEVELS = 3  # two parameters, and one level more to see whether the law holds
MIN_CYCLES = 2  # a spread per level needs two
LACK_OF_FIT_P = 0.001  # below this the P-V law does not describe the readings: refused
LEAK_T = 4.0  # a drift this many standard errors from zero is a leak
SETTLE_FRACTION = 0.02  # the 2 % settling time, as docs/physics.md's timing rows
DEFAULT_LEVELS = 5
KEY_DIGITS = 3  # levels are compared in kPa to 1 Pa
# The rise model's own error (smoothing, sampling, the law taken as quasi-static), as an sd:
# against the simulated plant (tests/system/test_characterise.py, ten set-ups) its resistance came
# 0.0-0.5 % low and its lag within 0.3 ms, with the cycles' spread alone giving +-0.3 %
RISE_MODEL_REL = 0.005
RISE_MODEL_LAG_S = 0.0005
RISE_DRAWS = 40  # draws of the fitted volumes carried into the rise's fit
# pressure-flow: the default sweep's top keeps the opening's flow (level / the path's stated
# resistance, laminar) this far inside the flow sensor's range. At the shipped profile's own
# 23.8 kPa the simulated HAFBLF0750 (+-0.75 SLPM) sat at its rail for 87-100 ms per cycle
FLOW_RANGE_USE = 0.9


class CharacteriseJournal(CycleJournal):
    """The finished free-air cycles of a characterisation (``OUT.cycles.jsonl``): each line
    one cycle's level, index and the numbers read from its trace."""

    KIND = "fluidsense characterise cycles"
    WHAT = "a characterisation journal"
    NUMBERS = ("p_eq_kpa", "noise_kpa", "lag_s", "settle_s", "drift_kpa_per_s", "drift_se_kpa_per_s", "rise_s")
    # a pressure-flow cycle's too (a tank cycle's line has none of them)
    FLOW_NUMBERS = ("v_eq_ml", "flow_peak_slpm", "flow_rail_s", "flow_settled_slpm", "flow_settled_se_slpm")

    @staticmethod
    def parse_entry(e: dict[str, Any]) -> dict[str, Any]:
        out = {"level_kpa": float(e["level_kpa"]), "k": int(e["k"]), "cycle_id": int(e["cycle_id"])}
        for key in CharacteriseJournal.NUMBERS:
            out[key] = None if e[key] is None else float(e[key])
        for key in CharacteriseJournal.FLOW_NUMBERS:
            if key in e:
                out[key] = None if e[key] is None else float(e[key])
        # the trace's sample period (journals written before it was kept have none: the
        # ISO valve's rise is then not fitted, said so)
        out["dt_s"] = None if e.get("dt_s") is None else float(e["dt_s"])
        rise = e["rise_t_s"]
        out["rise_t_s"] = None if rise is None else [float(x) for x in rise]
        if out["rise_t_s"] is not None and len(out["rise_t_s"]) != len(RISE_FRACTIONS):
            raise ValueError(f"rise_t_s has {len(out['rise_t_s'])} times, not {len(RISE_FRACTIONS)}")
        return out

    @staticmethod
    def check_entry(entry: dict[str, Any], plan: dict[str, Any]) -> str | None:
        if entry["level_kpa"] not in plan["levels_kpa"] or not 0 <= entry["k"] < plan["cycles"]:
            return f"cycle {entry['k']} at {entry['level_kpa']} kPa is not in the plan"
        if entry["p_eq_kpa"] is None:
            return "a cycle without an equilibrium"
        if (plan.get("sequence") or {}).get("method") == "pressure_flow" and entry.get("v_eq_ml") is None:
            return "a pressure-flow cycle without its integrated flow (v_eq_ml)"
        return None


# ------------------------------------------------------------------ the plan
def is_flow(profile: Profile) -> bool:
    """The pressure-flow circuit (method 2): V_eq at a regulated pressure, not P_eq from a tank."""
    return profile.sequence.method == "pressure_flow"


def flow_top_kpa(profile: Profile) -> float:
    """The highest level whose opening flow (laminar: level over the path's stated
    resistance, into an actuator at atmosphere) stays FLOW_RANGE_USE inside the flow
    sensor's range; the standard flow of eq. 3 is the pressure difference over r."""
    c = profile.circuit
    r = c.valve_resistance_pa_s_per_m3 + c.resistor_pa_s_per_m3
    q_max = min(abs(v) for v in profile.flow_sensor.range_slpm) * SLPM
    return FLOW_RANGE_USE * q_max * r / KPA


def default_levels(profile: Profile, n: int = DEFAULT_LEVELS) -> list[float]:
    """From 20 % of the profile's P0 up to it: the profile's own P0 is where its cycles run
    (its eq_sd is read there), nothing above it is asked of an actuator nobody has
    characterised yet, and the wider the span the better the compliance (the curvature of
    eq. 1) separates from the free volume. The pressure-flow circuit's top is lower where
    the opening's flow would pass the flow sensor's range (flow_top_kpa): a reading at the
    rail loses what it cut from V_eq."""
    p0 = profile.sequence.p0_kpa
    top = min(p0, flow_top_kpa(profile)) if is_flow(profile) else p0
    return [round(float(v), KEY_DIGITS) for v in np.linspace(0.2 * top, top, n)]


def check_plan(profile: Profile, levels: Sequence[float], cycles: int) -> list[float]:
    """The levels, sorted, or a ConfigError naming the option and the reason; before any
    valve moves."""
    method, kind = profile.sequence.method, profile.circuit.kind
    if method == "flow_control":
        raise ConfigError(f"profile {profile.name!r}: characterise sweeps a pressure (the tank circuit's P0, or the "
                          "pressure-flow circuit's regulated P0 with the flow integrated); the flow-control circuit "
                          "(sequence.method flow_control) feeds a flow programme instead and is not characterised "
                          "yet: characterise the actuator on a tank or pressure-flow circuit and keep the flow "
                          "controller's figures")
    if (method, kind) not in (("tank", "tank"), ("pressure_flow", "regulated")):
        raise ConfigError(f"profile {profile.name!r}: sequence.method {method!r} with a {kind!r} circuit is not "
                          "characterised (tank with a tank circuit, pressure_flow with a regulated one)")
    if method == "pressure_flow" and (profile.sequence.flow_window is None or not profile.circuit.flow_sensor):
        raise ConfigError(f"profile {profile.name!r}: the pressure-flow characterisation integrates the flow "
                          "sensor's reading: the circuit needs flow_sensor: true and the sequence a flow_window")
    if not hasattr(profile.actuator, "compliance_ml_per_kpa"):
        raise ConfigError(f"profile {profile.name!r}: actuator kind {profile.actuator.kind!r} has no free P-V "
                          "line (v0_ml, compliance_ml_per_kpa) to fit")
    if cycles < MIN_CYCLES:
        raise ConfigError(f"--cycles {cycles}: at least {MIN_CYCLES} per level are needed to state a spread")
    out = sorted({round(float(v), KEY_DIGITS) for v in levels})
    if len(out) < MIN_LEVELS:
        raise ConfigError(f"--levels: {len(out)} distinct level(s); the free P-V law has two parameters and needs "
                          f"at least {MIN_LEVELS} levels to show whether it holds")
    lim, margin, p0 = profile.limits, profile.p0_margin_kpa, profile.sequence.p0_kpa
    for v in out:
        if v == 0 or (v > 0) != (p0 > 0):
            raise ConfigError(f"--levels: {v:g} kPa: every level must drive the actuator the way its P0 does "
                              f"({p0:g} kPa)")
        if method == "pressure_flow" and v < 0:
            raise ConfigError(f"--levels: {v:g} kPa: the pressure-flow circuit's regulator sets pressures above "
                              "atmosphere")
        if not lim.min_kpa + margin <= v <= lim.max_kpa - margin:
            raise ConfigError(f"--levels: {v:g} kPa is outside the profile's limits [{lim.min_kpa:g}, "
                              f"{lim.max_kpa:g}] kPa less their {margin:.2f} kPa margin")
    return out


# ------------------------------------------------------------------ one cycle's trace
def read_trace(t: np.ndarray, p: np.ndarray, p_eq: float, noise: float, window: tuple[float, float]) -> dict:
    """Lag, 2 % settling time, the drift after settling and the 63 % rise time of one
    free-air cycle (t: s since the commanded opening; p: Pa, offset removed). Oriented so
    that the rise is upwards (vacuum too)."""
    sign = 1.0 if p_eq >= 0 else -1.0
    q, level = sign * p, abs(p_eq)
    out: dict[str, Any] = {"lag_s": None, "settle_s": None, "drift_kpa_per_s": None,
                           "drift_se_kpa_per_s": None, "rise_s": None, "rise_t_s": None, "dt_s": None}
    # lag: the rise's early part (out of the noise, below 30 %) extrapolated back to zero
    lo, hi = max(0.02 * level, 5 * noise), 0.3 * level
    first_hi = np.flatnonzero(q >= hi)
    if first_hi.size and lo < hi:
        end = first_hi[0]
        sel = np.flatnonzero(q[:end + 1] >= lo)
        sel = sel[sel >= (np.flatnonzero(q[:end + 1] < lo)[-1] + 1 if (q[:end + 1] < lo).any() else 0)]
        if sel.size >= 2:
            slope, icpt = np.polyfit(t[sel], q[sel], 1)
            if slope > 0:
                out["lag_s"] = float(-icpt / slope)
        elif sel.size == 1 and sel[0] > 0:  # a fast rise between two samples: the line through them
            i = sel[0]
            slope = (q[i] - q[i - 1]) / (t[i] - t[i - 1])
            if slope > 0:
                out["lag_s"] = float(t[i] - q[i] / slope)
    r63 = np.flatnonzero(q >= (1 - math.exp(-1)) * level)
    if r63.size and out["lag_s"] is not None:
        out["rise_s"] = float(t[r63[0]] - out["lag_s"])
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    w = smooth_width(dt)
    qs = smoothed(q, w)
    out["rise_t_s"] = rise_crossings(t, qs, level)
    out["dt_s"] = dt
    # settling: the last time the trace was outside the band before the window ended, on the
    # averaged trace (where the average is whole): a raw sample passes 5 sd of white noise
    # once in 1.7e6, and a pressure-flow cycle's 30 s hold has 3e4 of them (a hidden
    # actuator's characterisation was refused so, settled "after 28.8 s")
    band = max(SETTLE_FRACTION * level, 5 * noise)
    upto = t < window[1]
    whole = np.zeros(q.size, dtype=bool)
    whole[w // 2:q.size - w // 2] = True
    if qs is q:
        whole[:] = True
    outside = np.flatnonzero(upto & whole & (np.abs(qs - level) > band))
    out["settle_s"] = float(t[outside[-1] + 1]) if outside.size and outside[-1] + 1 < t.size else 0.0
    # drift from the window's start to the trace's end (a leak lets the pressure fall)
    after = t >= window[0]
    if after.sum() >= 10:
        tt, qq = t[after], q[after]
        slope, icpt = np.polyfit(tt, qq, 1)
        resid = qq - (slope * tt + icpt)
        # samples are not independent after smoothing by nothing: white sensor noise, so OLS se holds
        se = math.sqrt(float(resid @ resid) / (tt.size - 2) / float(((tt - tt.mean()) ** 2).sum()))
        out["drift_kpa_per_s"] = float(sign * slope / KPA)
        out["drift_se_kpa_per_s"] = se / KPA
    return out


def read_flow(t: np.ndarray, q: np.ndarray, offset: float, rail: tuple[float, float], quantum: float,
              window: tuple[float, float], offset_s: float) -> dict[str, Any]:
    """A pressure-flow cycle's flow (t: s since the commanded opening; q: standard m^3/s,
    offset removed): its peak, how long the raw reading sat at the sensor's rail (the
    integral then lost what the rail cut), and the mean flow over the settled window with
    its standard error (white noise over the window and over the offset window the offset
    was taken from: a leak keeps gas going in at the regulated pressure)."""
    raw = q + offset
    at_rail = (raw >= rail[1] - quantum / 2) | (raw <= rail[0] + quantum / 2)
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    sel = (t >= window[0]) & (t < window[1])
    out: dict[str, Any] = {"flow_peak_slpm": float(np.max(np.abs(q))) / SLPM, "flow_rail_s": float(at_rail.sum()) * dt,
                           "flow_settled_slpm": None, "flow_settled_se_slpm": None}
    if sel.sum() >= 10 and dt > 0:
        qq = q[sel]
        sd = float(qq.std(ddof=1))
        n_off = max(offset_s / dt, 1.0)
        out["flow_settled_slpm"] = float(qq.mean()) / SLPM
        out["flow_settled_se_slpm"] = math.sqrt(sd**2 / qq.size + sd**2 / n_off) / SLPM
    return out


def reading(res, level_kpa: float, k: int, window: tuple[float, float], profile: Profile | None = None
            ) -> dict[str, Any]:
    """One journal line from a finished cycle (with ``profile``'s flow sensor, a pressure-
    flow cycle's flow numbers too)."""
    t, p = res.trace
    p_eq = res.p_eq
    noise = res.p_sd
    numbers = read_trace(np.asarray(t), np.asarray(p), p_eq, noise, window)
    line = {"level_kpa": level_kpa, "k": k, "cycle_id": res.cycle_id, "p_eq_kpa": p_eq / KPA,
            "noise_kpa": noise / KPA, **numbers}
    if profile is not None and is_flow(profile):
        fs = profile.flow_sensor
        tf, qf = res.flow_trace
        line["v_eq_ml"] = res.v_eq / ML
        line.update(read_flow(np.asarray(tf), np.asarray(qf), res.flow_offset,
                              (fs.range_slpm[0] * SLPM, fs.range_slpm[1] * SLPM), fs.quantum_slpm * SLPM,
                              window, profile.sequence.offset_s))
    return line


# ------------------------------------------------------------------ the cycles
async def measure(port: TaskPort, levels: Sequence[float], cycles: int, journal: CharacteriseJournal,
                  place: Place | None = None, progress: Callable[[int], None] | None = None) -> list[dict]:
    """``cycles`` free-air cycles at each level; each finished one goes into ``journal`` as
    it completes (those already there are not run again). A run that cannot finish raises
    JobStopped with what it had done."""
    place = place or port.place
    profile = port.profile
    seq = profile.sequence
    window = (seq.windows[0].start_s, seq.windows[0].end_s)
    entries = journal.entries
    total = len(levels) * cycles
    try:
        await place(EmptyScene())
        # the levels interleaved (one pass over all, then the next): every cycle sets the
        # regulator anew, so the spread at a level holds its setting error too. Through
        # the box the regulator lands anew only when its setpoint changes: cycles run
        # level by level shared one error and spread 0.0055 kPa, while the levels' means
        # scattered 0.016 kPa about the law (refused as a lack of fit)
        for k in range(cycles):
            for level in levels:
                if any(e["level_kpa"] == level and e["k"] == k for e in entries):
                    continue
                res = await port.run_cycle(p0_kpa=level, label=f"characterise P0={level:g}")
                if not res.ok or res.trace is None or res.p_eq is None:
                    raise FluidsenseError(f"free-air cycle {res.cycle_id} at {level:g} kPa ended: {res.aborted}")
                if is_flow(profile) and (res.v_eq is None or res.flow_trace is None):
                    raise FluidsenseError(f"free-air cycle {res.cycle_id} at {level:g} kPa read no flow: the "
                                          "pressure-flow characterisation needs the cell's flow channel")
                # off the event loop: the sampler shares it, and a real-time loop held up by a
                # fit or an fsync on a busy host latches an overrun fault (seen through the box)
                line = await asyncio.to_thread(reading, res, level, k, window, profile)
                await asyncio.to_thread(journal.add, line)
                if progress is not None:
                    progress(1)
    except (asyncio.CancelledError, KeyboardInterrupt):
        raise
    except FluidsenseError as exc:
        partial = {"completed": False, "cycles_done": len(entries), "cycles_total": total,
                   "journal": str(journal.path), "fault": fault_dict(port), "error": f"{type(exc).__name__}: {exc}"}
        raise JobStopped(stopped_message("characterisation", port, exc, f"{len(entries)} of {total} cycles")
                         + f"; finished cycles are kept in {journal.path}: run again with --resume", partial,
                         partial["fault"]) from exc
    return entries


# ------------------------------------------------------------------ the fit
def _mean_over_cycles(values: list[tuple[float, float]]) -> tuple[float, float, float]:
    """Each cycle's (value, its own standard error): the mean, its standard error (the
    cycles' scatter, never below what the cycles' own errors give) and the 95 % half-width."""
    x = np.array([v for v, _ in values])
    se = float(x.std(ddof=1)) / math.sqrt(x.size) if x.size > 1 else values[0][1]
    se = max(se, math.sqrt(sum(s**2 for _, s in values)) / x.size)
    return float(x.mean()), se, _t95(x.size - 1) * se


class FitRefused(FluidsenseError):
    """The readings do not support a profile: ``reasons`` says why, each on its own."""

    def __init__(self, reasons: list[str], result: Characterisation | None = None):
        self.reasons, self.result = reasons, result
        super().__init__("characterisation refused: " + "; ".join(reasons))


@dataclass
class Characterisation:
    fitted: list[FittedNumber]
    measured: list[FittedNumber]
    kept: dict[str, str]
    notes: list[str]
    residual_kpa: float
    pure_error_kpa: float
    levels: list[dict[str, float]] = field(default_factory=list)  # per level: P0, mean, sd, n, fitted
    pv_cov: list[list[float]] | None = None  # covariance of (v0 ml, c ml/kPa): the contact fit carries it
    residual_ml: float | None = None  # pressure-flow: the V_eq fit's rms residual over the levels' means
    pure_error_ml: float | None = None  # pressure-flow: the pooled cycle-to-cycle sd of V_eq about the law

    def value(self, name: str) -> float | None:
        for f in self.fitted:
            if f.field == name:
                return f.value
        return None

    def to_dict(self) -> dict[str, Any]:
        return {"fitted": [f.model_dump() for f in self.fitted], "measured": [f.model_dump() for f in self.measured],
                "kept": self.kept, "notes": self.notes, "residual_kpa": self.residual_kpa,
                "pure_error_kpa": self.pure_error_kpa, "levels": self.levels,
                **({} if self.residual_ml is None else {"residual_ml": self.residual_ml,
                                                         "pure_error_ml": self.pure_error_ml})}


def _t95(dof: int) -> float:
    return float(stats.t.ppf(0.975, max(dof, 1)))


def _mean_interval(values: Sequence[float]) -> tuple[float, float, float]:
    x = np.asarray(values, dtype=float)
    m = float(x.mean())
    if x.size < 2:
        return m, m, m
    h = _t95(x.size - 1) * float(x.std(ddof=1)) / math.sqrt(x.size)
    return m, m - h, m + h


def fit_rise(times: Sequence[float], v_tank: float, v_act0: float, c: float, p0: float, p_atm: float
             ) -> tuple[float, float, float]:
    """(lag s, laminar path resistance Pa s/m^3, rms time residual s) of one rise, from the
    times it crossed RISE_FRACTIONS of its equilibrium. The model: tank at P0 and the
    actuator side (v_act0 + c p, from atmosphere, on its law) joined by a laminar path
    (eq. 3, the amount moved p_std q); isothermal. Then dp/dt = g(p) / R, so the time to
    reach p is lag + R * I(p), I(p) = integral of 1/g from 0 to p: linear in (lag, R), and
    fitted so. Each crossing is compared at the same fraction of the model's equilibrium
    (the cycle's own P0 differs from the commanded by the regulator's error)."""
    m_total = (p0 + p_atm) * v_tank + p_atm * v_act0
    p_eq = float(free_equilibrium(p0, v_tank, v_act0, c, p_atm))
    grid = np.linspace(0.0, max(RISE_FRACTIONS) * p_eq, 2001)
    m_act = (grid + p_atm) * (v_act0 + c * grid)
    pt = (m_total - m_act) / v_tank - p_atm
    cap = v_act0 + c * grid + (grid + p_atm) * c  # d(p v)/dp of the actuator side
    inv_g = cap / (p_atm * (pt - grid))
    integral = integrate.cumulative_trapezoid(inv_g, grid, initial=0.0)
    x = np.interp(np.array(RISE_FRACTIONS) * p_eq, grid, integral)
    a = np.column_stack([np.ones_like(x), x])
    coef, *_ = np.linalg.lstsq(a, np.asarray(times, dtype=float), rcond=None)
    resid = np.asarray(times) - a @ coef
    return float(coef[0]), float(coef[1]), float(np.sqrt(np.mean(resid**2)))


@dataclass
class FlowLaw:
    """The pressure-flow circuit's free P-V law fitted to (Pe, V_eq) per cycle."""

    x: np.ndarray  # (v side ml, c ml/kPa)
    cov: np.ndarray
    dof_pure: int
    s_pure_ml: float
    residual_ml: float
    residual_kpa: float  # the level means' V residual carried to pressure through the law's slope
    f_ratio: float
    p_lof: float
    rows: list[dict[str, float]]


def flow_law(by_level: dict[float, list[dict]], p_atm: float) -> FlowLaw:
    """Least squares of every cycle's V_eq on its own measured Pe:
    ``V_eq p_std = Pe v_side + c Pe (Pe + Pa)`` (isothermal, from atmosphere; p_std the
    circuit's p_atm, as eq. 3). Linear in (v_side, c), so the least squares is exact. The
    pure error is the cycles' scatter about the law within each level (each cycle at its
    own Pe: the regulator's landing error is in the abscissa, not the spread), the lack of
    fit the levels' mean residuals against it; the covariance is the pure error's, inflated
    by the lack-of-fit ratio when the means scatter more."""
    levels = sorted(by_level)
    pe = np.array([e["p_eq_kpa"] * KPA for lv in levels for e in by_level[lv]])
    v = np.array([e["v_eq_ml"] * ML for lv in levels for e in by_level[lv]])
    group = np.array([i for i, lv in enumerate(levels) for _ in by_level[lv]])
    p_std = p_atm
    a = np.column_stack([pe / p_std * ML, pe * (pe + p_atm) / p_std * ML / KPA])
    x, *_ = np.linalg.lstsq(a, v, rcond=None)
    r = v - a @ x
    n = np.bincount(group).astype(float)
    r_mean = np.bincount(group, weights=r) / n
    ss_pure = float(((r - r_mean[group]) ** 2).sum())
    dof_pure = int(pe.size - len(levels))
    dof_lof = len(levels) - 2
    s_pure = math.sqrt(ss_pure / dof_pure) if dof_pure > 0 else 0.0
    ss_lof = float((n * r_mean**2).sum())
    f_ratio = (ss_lof / dof_lof) / s_pure**2 if dof_lof > 0 and s_pure > 0 else 0.0
    p_lof = float(stats.f.sf(f_ratio, dof_lof, dof_pure)) if dof_lof > 0 and s_pure > 0 else 1.0
    cov = np.linalg.inv(a.T @ a) * s_pure**2 * max(1.0, f_ratio)
    # the law's slope dV/dPe at each level: a V residual is worth residual / slope in pressure
    pe_mean = np.bincount(group, weights=pe) / n
    slope = (x[0] * ML + x[1] * ML / KPA * (2 * pe_mean + p_atm)) / p_std
    rows = []
    for i, lv in enumerate(levels):
        sel = group == i
        vv = v[sel]
        rows.append({"p0_kpa": lv, "mean_kpa": float(pe_mean[i] / KPA),
                     "sd_kpa": float(pe[sel].std(ddof=1) / KPA), "n": int(n[i]),
                     "v_eq_mean_ml": float(vv.mean() / ML), "v_eq_sd_ml": float(vv.std(ddof=1) / ML),
                     "fitted_ml": float((vv.mean() - r_mean[i]) / ML)})
    return FlowLaw(x, cov, dof_pure, s_pure / ML, math.sqrt(float(np.mean(r_mean**2))) / ML,
                   math.sqrt(float(np.mean((r_mean / slope) ** 2))) / KPA, f_ratio, p_lof, rows)


def fit(entries: Sequence[dict[str, Any]], start: Profile) -> Characterisation:
    """The profile's numbers from the free-air cycles, or FitRefused naming why.

    The P-V law: least squares of the levels' mean equilibria (each weighted by its cycles)
    against eq. 1 in (v0 + hose, c); the covariance from the pooled cycle-to-cycle spread
    (the pure error: what the cycles at one level disagree by), inflated by the lack-of-fit
    ratio when the means scatter more than that; 95 % intervals with Student's t on the
    pure error's degrees of freedom."""
    c_cfg, act, seq = start.circuit, start.actuator, start.sequence
    p_atm, v_tank = c_cfg.p_atm, c_cfg.tank_m3
    hose = c_cfg.hose.volume_m3 if c_cfg.hose is not None else 0.0
    port = PORT_VOLUME_M3 if (c_cfg.valve is not None and c_cfg.resistor_pa_s_per_m3 > 0) else 0.0
    fixed = hose + port  # stated by the config, not measured
    refused: list[str] = []
    by_level: dict[float, list[dict]] = {}
    for e in entries:
        by_level.setdefault(e["level_kpa"], []).append(e)
    levels = sorted(by_level)
    if len(levels) < MIN_LEVELS:
        raise FitRefused([f"too few levels: {len(levels)} (at least {MIN_LEVELS})"])
    counts = [len(by_level[v]) for v in levels]
    if min(counts) < MIN_CYCLES:
        raise FitRefused([f"too few cycles at a level: {min(counts)} (at least {MIN_CYCLES} per level)"])

    p0 = np.array([v * KPA for v in levels])
    ys = [np.array([e["p_eq_kpa"] * KPA for e in by_level[v]]) for v in levels]
    n = np.array(counts, dtype=float)
    means = np.array([y.mean() for y in ys])
    n_total, n_lev = int(n.sum()), len(levels)
    dof_pure = n_total - n_lev
    ss_pure = float(sum(((y - y.mean()) ** 2).sum() for y in ys))
    s_pure = math.sqrt(ss_pure / dof_pure)
    if s_pure <= 0:
        raise FitRefused(["the cycles at each level read exactly the same: no spread to state an uncertainty from"])

    flow = is_flow(start)
    law_flow = None
    if flow:
        missing = [e["cycle_id"] for e in entries if e.get("v_eq_ml") is None]
        if missing:
            raise FitRefused([f"{len(missing)} cycle(s) without an integrated flow (v_eq_ml): cycles {missing[:5]}"])
        law_flow = flow_law(by_level, p_atm)
        sol_x, cov, f_ratio, p_lof = law_flow.x, law_flow.cov, law_flow.f_ratio, law_flow.p_lof
        dof_fit = law_flow.dof_pure
        residual = law_flow.residual_kpa
    else:
        def resid(x: np.ndarray) -> np.ndarray:
            v_act0, c = x[0] * ML, x[1] * ML / KPA
            return np.sqrt(n) * (free_equilibrium(p0, v_tank, v_act0, c, p_atm) - means) / s_pure

        x0 = np.array([act.v0_ml + fixed / ML, act.compliance_ml_per_kpa])
        sol = optimize.least_squares(resid, x0, x_scale=x0, method="lm")
        jac = sol.jac
        cov = np.linalg.inv(jac.T @ jac)
        ss_lof = float(sol.fun @ sol.fun)  # in units of the pure error's variance
        dof_lof = n_lev - 2
        f_ratio = ss_lof / dof_lof if dof_lof > 0 else 0.0
        p_lof = float(stats.f.sf(f_ratio, dof_lof, dof_pure)) if dof_lof > 0 else 1.0
        cov = cov * max(1.0, f_ratio)
        sol_x, dof_fit = sol.x, dof_pure
        fitted_eq = free_equilibrium(p0, v_tank, sol_x[0] * ML, sol_x[1] * ML / KPA, p_atm)
        residual = math.sqrt(float(np.mean((fitted_eq - means) ** 2))) / KPA
    if p_lof < LACK_OF_FIT_P:
        refused.append(f"the free P-V law does not fit: the levels' means scatter {math.sqrt(f_ratio):.2g} times "
                       f"the cycles' own spread about it (lack-of-fit p = {p_lof:.2g}; a law that bends, a leak, "
                       "or a volume that is not the config's)")
    t95 = _t95(dof_fit)
    v_side, c_fit = float(sol_x[0]), float(sol_x[1])
    se_v, se_c = math.sqrt(cov[0, 0]), math.sqrt(cov[1, 1])
    v0_ml = v_side - fixed / ML
    if v0_ml - t95 * se_v <= 0 or c_fit - t95 * se_c <= 0:
        refused.append(f"the fitted volume or compliance is not positive within its interval (v0 {v0_ml:.4g} "
                       f"+- {t95 * se_v:.2g} ml, c {c_fit:.4g} +- {t95 * se_c:.2g} ml/kPa): the levels do not "
                       "span enough of the law, or the stated " + ("flow sensor" if flow else "tank")
                       + " or hose is wrong")
    if flow:
        scale = ("in absolute volume, scaled by the flow sensor: its standard conditions taken as the circuit's "
                 f"p_atm ({p_atm / KPA:g} kPa) at the gas's temperature (eq. 3); a sensor that reads k times the "
                 "true standard flow (its calibration, or standard conditions of another temperature: 0 against "
                 "20 degC is 7 %) gives k times v0 and c. Not in the interval")
        method = (f"V_eq p_std = Pe v0 + c Pe (Pe + Pa) least squares over {law_flow.dof_pure + n_lev} cycles at "
                  f"{n_lev} levels (each at its own measured Pe; interval from the cycles' scatter about the law, "
                  f"{law_flow.dof_pure} degrees of freedom)")
    else:
        scale = (f"scaled by the stated tank ({c_cfg.tank_l:g} L, circuit.tank_l)"
                 + (f" and hose ({hose / ML:.4g} ml, circuit.hose)" if hose else "")
                 + ": the equilibria show only ratios of volumes; if the tank is k times the stated one, so are "
                   "v0 and c")
        method = f"eq. 1 least squares over {n_lev} levels x {counts[0]} cycles"
    fitted = [
        FittedNumber(field="actuator.v0_ml", value=v0_ml, lo95=v0_ml - t95 * se_v, hi95=v0_ml + t95 * se_v,
                     unit="ml", how=f"{method}, {scale}"
                     + (f"; the hose's {hose / ML:.4g} ml taken off the fitted side volume" if fixed else "")),
        FittedNumber(field="actuator.compliance_ml_per_kpa", value=c_fit, lo95=c_fit - t95 * se_c,
                     hi95=c_fit + t95 * se_c, unit="ml/kPa",
                     how=f"{'the' if flow else 'eq. 1, the'} same fit, {scale}"),
    ]
    measured: list[FittedNumber] = []
    kept: dict[str, str] = {}
    notes = [f"correlation of v0 and c in the fit: {cov[0, 1] / (se_v * se_c):+.3f}"]

    # cycle-to-cycle spread at the profile's own P0 (the level nearest it), as sequence.eq_sd_kpa
    near = min(levels, key=lambda v: abs(v - seq.p0_kpa))
    y_near = ys[levels.index(near)]
    k_near = y_near.size
    sd_near = float(y_near.std(ddof=1)) / KPA
    lo_sd = sd_near * math.sqrt((k_near - 1) / stats.chi2.ppf(0.975, k_near - 1))
    hi_sd = sd_near * math.sqrt((k_near - 1) / stats.chi2.ppf(0.025, k_near - 1))
    fitted.append(FittedNumber(field="sequence.eq_sd_kpa", value=sd_near, lo95=lo_sd, hi95=hi_sd, unit="kPa",
                               how=f"sd of the free-air equilibrium over {k_near} cycles at {near:g} kPa "
                               f"(chi-square interval)" + ("" if near == seq.p0_kpa else
                                                             f"; the profile's P0 is {seq.p0_kpa:g} kPa")))
    measured.append(FittedNumber(field="pure_error_kpa", value=s_pure / KPA, lo95=s_pure / KPA,
                                 hi95=s_pure / KPA, unit="kPa", how=f"pooled sd of the equilibrium over all levels "
                                 f"({dof_pure} degrees of freedom)"))
    if flow:
        measured.append(FittedNumber(field="pure_error_ml", value=law_flow.s_pure_ml, lo95=law_flow.s_pure_ml,
                                     hi95=law_flow.s_pure_ml, unit="ml", how="pooled sd of V_eq about the law "
                                     f"within each level ({law_flow.dof_pure} degrees of freedom): the flow "
                                     "sensor's repeatability and the integrated offset's error"))
        peaks = [e["flow_peak_slpm"] for e in entries if e.get("flow_peak_slpm") is not None]
        railed = [e for e in entries if (e.get("flow_rail_s") or 0.0) > 0]
        if peaks:
            measured.append(FittedNumber(field="flow_peak_slpm", value=max(peaks), lo95=min(peaks),
                                         hi95=max(peaks), unit="SLPM", how="the largest flow read at the opening, "
                                         "offset removed (interval: the cycles' range)"))
        if railed:
            worst = max(railed, key=lambda e: e["flow_rail_s"])
            refused.append(f"the flow sensor read its rail in {len(railed)} cycle(s), for up to "
                           f"{1e3 * worst['flow_rail_s']:.0f} ms at {worst['level_kpa']:g} kPa: V_eq lost what "
                           "the rail cut; lower the top level (--levels) below where the opening's flow reaches "
                           "the sensor's range (flow_sensor.range_slpm), or a larger resistor")

    # the sensor's noise: the settled window's sample sd, pooled over every cycle
    noise = np.array([e["noise_kpa"] for e in entries])
    noise_rms = float(np.sqrt(np.mean(noise**2)))
    lo_n, hi_n = float(np.min(noise)), float(np.max(noise))
    fitted.append(FittedNumber(field="sensor.noise_sd_kpa", value=noise_rms, lo95=min(lo_n, noise_rms),
                               hi95=max(hi_n, noise_rms), unit="kPa",
                               how=f"rms of the sample sd in the settled window ({seq.windows[0].start_s:g}-"
                               f"{seq.windows[0].end_s:g} s) over {len(entries)} cycles; the interval is the "
                               "cycles' range (quantisation included)"))

    # the lag: where the rise starts, after the commanded opening
    # not for the pressure-flow circuit: its rise from a held pressure is exponential from the
    # start, and the early part extrapolated back says nothing of the valve (it came 30 ms early)
    lags = [e["lag_s"] for e in entries if e["lag_s"] is not None and not flow]
    if len(lags) >= MIN_CYCLES:
        m, lo, hi = _mean_interval(lags)
        measured.append(FittedNumber(field="rise_start_s", value=m, lo95=lo, hi95=hi, unit="s",
                                     how=f"mean over {len(lags)} cycles of the rise's early part (out of the noise, "
                                     "below 30 %) extrapolated back to zero, from the commanded opening: early by "
                                     "the rise's curvature (on the simulated laminar circuit 9.5 ms for a 12 ms "
                                     "delay), so not written"))
    kept["circuit.valve_delay_s"] = ("the rise's start is fitted only with a laminar circuit's rise (below); "
                                     "this circuit's rise is not modelled here")

    # the settling time (2 %), and whether the window reads after it
    settles = [e["settle_s"] for e in entries if e["settle_s"] is not None]
    m_s, lo_s, hi_s = _mean_interval(settles)
    measured.append(FittedNumber(field="settle_s", value=m_s, lo95=lo_s, hi95=hi_s, unit="s",
                                 how=f"mean over {len(settles)} cycles of the last time before the window's end "
                                 f"that the trace was more than {SETTLE_FRACTION:.0%} of P_eq (or 5 x the noise) "
                                 "from it"))
    if max(settles) > seq.windows[0].start_s:
        refused.append(f"the window starts at {seq.windows[0].start_s:g} s but the actuator settled only after "
                       f"{max(settles):.3g} s in a cycle: its readings are not equilibria (a slower actuator, a "
                       "leak or a larger resistance than the profile's): lengthen sequence.windows")

    # the leak: the drift after settling, over every cycle
    drifts = [(e["drift_kpa_per_s"], e["drift_se_kpa_per_s"]) for e in entries if e["drift_kpa_per_s"] is not None]
    if drifts:
        m_d, se_d, h_d = _mean_over_cycles(drifts)
        measured.append(FittedNumber(field="drift_kpa_per_s", value=m_d, lo95=m_d - h_d, hi95=m_d + h_d,
                                     unit="kPa/s", how="mean slope of the free-air trace from the window's start to "
                                     "the valve's closing, oriented away from atmosphere (a leak is negative)"))
        if flow:  # the regulator holds the pressure: a leak shows in the flow, not as a drift
            kept["circuit.leak_resistance_pa_s_per_m3"] = "judged on the settled flow (below)"
        elif m_d < -LEAK_T * se_d:
            refused.append(f"a leak: the settled free-air pressure falls {-m_d:.3g} kPa/s (+- {h_d:.2g}, "
                           f"{-m_d / se_d:.1f} standard errors): an equilibrium with a leak is not eq. 1's; find "
                           "the leak and characterise again")
            kept["circuit.leak_resistance_pa_s_per_m3"] = "a leak was seen: the fit is refused"
        else:
            kept["circuit.leak_resistance_pa_s_per_m3"] = (f"no leak shown (drift {m_d:+.2g} +- {h_d:.2g} kPa/s): "
                                                          "the starting value is kept")

    # pressure-flow: the leak is the flow still going in over the settled window (gas lost
    # to the air at the regulated pressure); the offset's own error is common to a cycle's window
    settled = [(e["flow_settled_slpm"], e["flow_settled_se_slpm"]) for e in entries
               if e.get("flow_settled_slpm") is not None]
    if flow and settled:
        m_q, se_q, h_q = _mean_over_cycles(settled)
        measured.append(FittedNumber(field="settled_flow_slpm", value=m_q, lo95=m_q - h_q, hi95=m_q + h_q,
                                     unit="SLPM", how=f"mean flow into the actuator over the window "
                                     f"({seq.windows[0].start_s:g}-{seq.windows[0].end_s:g} s), offset removed, "
                                     f"over {len(settled)} cycles (a leak is positive)"))
        if m_q > LEAK_T * se_q:
            refused.append(f"a leak: once settled, {m_q:.3g} SLPM still flows in at the regulated pressure "
                           f"(+- {h_q:.2g}, {m_q / se_q:.1f} standard errors): V_eq holds what leaked, not the "
                           "actuator's law; find the leak and characterise again")
            kept["circuit.leak_resistance_pa_s_per_m3"] = "a leak was seen: the fit is refused"
        else:
            kept["circuit.leak_resistance_pa_s_per_m3"] = (f"no leak shown (settled flow {m_q:+.2g} +- {h_q:.2g} "
                                                          "SLPM): the starting value is kept")

    # the path's resistance from the rise (laminar circuits without a hose only)
    rises = [e["rise_s"] for e in entries if e["rise_s"] is not None]
    if rises:
        m_r, lo_r, hi_r = _mean_interval(rises)
        measured.append(FittedNumber(field="rise_63_s", value=m_r, lo95=lo_r, hi95=hi_r, unit="s",
                                     how="time from the rise's start to 63 % of P_eq, mean over cycles"))
    laminar = c_cfg.valve is None and c_cfg.hose is None and c_cfg.thermal.model == "isothermal" and not flow
    if laminar:
        top = max(abs(v) for v in levels)
        used = [e for e in entries if e["rise_t_s"] is not None and abs(e["level_kpa"]) >= RISE_MIN_LEVEL * top]

        def rises(v_act0: float, c: float) -> tuple[list[float], list[float], list[float]]:
            out = [fit_rise(e["rise_t_s"], v_tank, v_act0, c, e["level_kpa"] * KPA, p_atm) for e in used]
            return [x[0] for x in out], [x[1] for x in out], [x[2] for x in out]

        rise_lags, rs, rms = rises(v_side * ML, c_fit * ML / KPA)
        # the rise's model uses the fitted volumes: carry their uncertainty (draws from the
        # P-V fit's covariance, a fixed seed: the same readings give the same intervals)
        draws = np.random.default_rng(0).multivariate_normal(sol_x, cov, size=RISE_DRAWS if used else 0)
        spread_lag, spread_r = [], []
        for v_d, c_d in draws:
            if v_d > 0 and c_d > 0:
                dl, dr, _ = rises(v_d * ML, c_d * ML / KPA)
                spread_lag.append(float(np.mean(dl)))
                spread_r.append(float(np.mean(dr)))

        def widened(values: list[float], spread: list[float], floor: float) -> tuple[float, float, float]:
            m, lo, hi = _mean_interval(values)
            extra = 1.96 * float(np.std(spread, ddof=1)) if len(spread) > 1 else 0.0
            h = math.sqrt((hi - m) ** 2 + extra**2 + (1.96 * floor) ** 2)
            return m, m - h, m + h

        if len(rise_lags) >= MIN_CYCLES:
            m, lo, hi = widened(rise_lags, spread_lag, RISE_MODEL_LAG_S)
            kept.pop("circuit.valve_delay_s", None)
            fitted.append(FittedNumber(field="circuit.valve_delay_s", value=max(m, 0.0), lo95=max(min(lo, m), 0.0),
                                       hi95=max(hi, 0.0), unit="s", how=f"mean over {len(rise_lags)} rises (levels "
                                       f"from {RISE_MIN_LEVEL:.0%} of the top) of the start of the laminar two-volume "
                                       "rise fitted to its 10-90 % crossings (with the resistance below), from the "
                                       "commanded opening; the interval carries the fitted volumes' uncertainty"))
            notes.append(f"rise fit: rms time residual {1e3 * float(np.sqrt(np.mean(np.square(rms)))):.3g} ms "
                         "over the 10-90 % crossings")
        if len(rs) >= MIN_CYCLES:
            m_r, lo_r, hi_r = widened(rs, spread_r, RISE_MODEL_REL * float(np.mean(rs)))
            valve = c_cfg.valve_resistance_pa_s_per_m3
            if m_r - valve > 0 and lo_r - valve > 0:
                fitted.append(FittedNumber(field="circuit.resistor_pa_s_per_m3", value=m_r - valve,
                                           lo95=lo_r - valve, hi95=hi_r - valve, unit="Pa s/m^3",
                                           how=f"the path's resistance fitted to {len(rs)} rises (isothermal, "
                                           "the fitted volumes and their uncertainty, the actuator on its law, "
                                           "quasi-static; the model's own error taken as "
                                           f"{RISE_MODEL_REL:.1%} sd) less the valve's "
                                           f"{valve:.3g} (kept: the rig shows only their sum)"))
                kept["circuit.valve_resistance_pa_s_per_m3"] = "the rig shows only the path's sum; the valve's kept"
            else:
                measured.append(FittedNumber(field="path_resistance_pa_s_per_m3", value=m_r, lo95=lo_r, hi95=hi_r,
                                             unit="Pa s/m^3", how="the path's resistance from the rises: not "
                                             "above the valve's assumed figure, so neither is changed"))
                kept["circuit.resistor_pa_s_per_m3"] = "the rise's resistance is within the valve's assumed figure"
        else:
            kept["circuit.resistor_pa_s_per_m3"] = "too few rises could be fitted"
    elif c_cfg.valve is not None and not flow and refused:
        # the rise's model is built on the fitted volumes: none to build it on
        for name in ("circuit.valve.sonic_conductance_dm3_per_s_bar", "circuit.valve.critical_ratio",
                     "circuit.valve_delay_s"):
            kept[name] = "the free P-V fit does not hold (above): the rise's model needs its volumes"
    elif c_cfg.valve is not None and not flow:
        # an ISO 6358 valve: C from the rise against the simulated plant's own network
        iso = fit_iso_valve(entries, start, v_side, c_fit, fixed / ML, cov, noise_rms)
        kept.pop("circuit.valve_delay_s", None)
        fitted += iso.fitted
        measured += iso.measured
        kept.update(iso.kept)
        notes += iso.notes
        refused += iso.refused
        kept["circuit.valve_resistance_pa_s_per_m3"] = "not used: the circuit's valve is ISO 6358"
        if c_cfg.resistor_pa_s_per_m3 > 0:
            kept["circuit.resistor_pa_s_per_m3"] = ("in series with the ISO valve: the rise shows them together; "
                                                    "the resistor is kept and C is fitted for the pair")
    else:
        why = ("the pressure-flow circuit: its rise (regulator, buffer and path) is not modelled here" if flow else
               "a hose with a laminar valve: the rise is not a laminar two-volume one, and its resistance is "
               "not fitted yet")
        if flow:
            kept["circuit.valve_delay_s"] = why
        for name in ("circuit.valve", "circuit.valve_resistance_pa_s_per_m3", "circuit.resistor_pa_s_per_m3"):
            kept[name] = why

    scale_kept = ({"circuit.buffer_l": "the regulator holds the pressure: the buffer's volume does not enter V_eq",
                   "flow_sensor": "the scale of every volume: its calibration and standard conditions as the rig "
                                  "has them (the fit takes p_std as circuit.p_atm)"} if flow else
                  {"circuit.tank_l": "the scale of every volume: as the config states it (the tank's label)"})
    for name, why in {
        **scale_kept,
        "circuit.hose": "as the config states it (bore and length)",
        "circuit.regulator_repeatability_kpa": "not separable from the other causes of the spread; "
                                               "sequence.eq_sd_kpa holds the spread itself",
        "actuator (other fields)": "the contact law needs objects of known size (--targets): kept",
        "sensor.offset_kpa": "removed per cycle before the valve opens; not a property of the actuator",
    }.items():
        kept.setdefault(name, why)
    if flow:
        level_rows = law_flow.rows
    else:
        level_rows = [{"p0_kpa": lv, "mean_kpa": float(m / KPA), "sd_kpa": float(y.std(ddof=1) / KPA),
                       "n": int(k), "fitted_kpa": float(f / KPA)}
                      for lv, m, y, k, f in zip(levels, means, ys, counts, fitted_eq)]
    result = Characterisation(fitted, measured, kept, notes, residual, s_pure / KPA, level_rows,
                              pv_cov=[[float(x) for x in row] for row in cov],
                              residual_ml=law_flow.residual_ml if flow else None,
                              pure_error_ml=law_flow.s_pure_ml if flow else None)
    if refused:
        raise FitRefused(refused, result)
    return result


# ------------------------------------------------------------------ the profile
CONTACT_OTHERS = "neither free air nor rigid, centred targets show them: kept"
FIELD_UNITS = {"actuator.v0_ml": "ml", "actuator.compliance_ml_per_kpa": "ml/kPa"}


def characterised_profile(start_data: dict[str, Any], start: Profile, result: Characterisation, *, name: str,
                          rig: str, config: str, from_profile: str, levels: Sequence[float], cycles: int,
                          cycle_ids: Sequence[int], date: datetime.datetime | None = None,
                          contact: Any = None, contact_block: dict[str, Any] | None = None) -> dict[str, Any]:
    """The starting profile's document with the fitted fields set and the provenance
    block added; checked by the Profile model before it is returned. ``contact`` (a
    tasks.contact.ContactFit) adds the contact law's fitted fields, ``contact_block`` its
    provenance (tasks.contact.provenance)."""
    data = {**start_data}
    for key in ("circuit", "actuator", "sensor", "sequence"):
        data[key] = dict(data.get(key) or {})
    fitted, kept, notes = list(result.fitted), dict(result.kept), list(result.notes)
    if contact is not None:
        fitted += contact.fitted
        kept.update(contact.kept)
        kept["actuator (other fields)"] = CONTACT_OTHERS
        notes += contact.notes
    for f in fitted:
        *path, key = f.field.split(".")
        node = data
        for part in path:  # a nested field (circuit.valve.sonic_conductance_dm3_per_s_bar): copied, then set
            node[part] = dict(node.get(part) or {})
            node = node[part]
        node[key] = float(f"{f.value:.6g}")
    data["name"] = name
    data["description"] = (f"{start.name} characterised on {rig} "
                           f"({(date or datetime.datetime.now(datetime.UTC)).date().isoformat()})")
    when = (date or datetime.datetime.now(datetime.UTC)).isoformat(timespec="seconds")
    prov = Provenance(date=when, rig=rig, config=config, from_profile=from_profile, levels_kpa=list(levels),
                      cycles_per_level=cycles, cycle_ids=list(cycle_ids), residual_kpa=result.residual_kpa,
                      pure_error_kpa=result.pure_error_kpa, residual_ml=result.residual_ml,
                      pure_error_ml=result.pure_error_ml, fitted=fitted, measured=result.measured,
                      kept=kept, notes=notes, contact=contact_block)
    data["provenance"] = prov.model_dump(mode="json")
    Profile.model_validate(data)  # a profile nobody can load is never written
    return data


def profile_comments(result: Characterisation, prov_line: str, contact: Any = None) -> str:
    """The header a characterised profile carries: every fitted number with its interval,
    and what was kept, in words (the provenance block holds the same, for programs)."""
    fitted, kept = list(result.fitted), dict(result.kept)
    if contact is not None:
        fitted += contact.fitted
        kept.update(contact.kept)
        kept["actuator (other fields)"] = CONTACT_OTHERS
    lines = [f"# Characterised by fluidsense characterise: {prov_line}", "# Fitted on the rig (95 % intervals):"]
    for f in fitted:
        lines.append(f"#   {f.field} = {f.value:.6g} {f.unit} [{f.lo95:.6g}, {f.hi95:.6g}]")
    lines.append("# Kept from the starting profile:")
    for k, why in kept.items():
        lines.append(f"#   {k}: {why}")
    if result.residual_ml is not None:
        lines.append(f"# P-V fit (V_eq against Pe) residual {result.residual_ml:.3g} ml rms over the levels' means "
                     f"({result.residual_kpa:.3g} kPa through the law's slope); the cycles' own spread "
                     f"{result.pure_error_ml:.3g} ml")
    else:
        lines.append(f"# P-V fit residual {result.residual_kpa:.3g} kPa rms over the levels' means; the cycles' "
                     f"own spread {result.pure_error_kpa:.3g} kPa")
    if contact is not None:
        lines.append(f"# Contact law from {len(contact.targets)} targets at P0 (provenance.contact: the readings, "
                     "the fitted law's and the simulated cell's)")
    return "\n".join(lines) + "\n"


def v_tank_of(profile: Profile) -> float:
    return profile.circuit.tank_l * LITRE
