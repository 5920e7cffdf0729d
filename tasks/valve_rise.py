"""An ISO 6358 valve's sonic conductance C from the free-air rises of a tank circuit's
characterisation (issue 36 item 1, "the valve's conductance from the rise").

The rig's rise is the journal's crossings: when each cycle's trace, averaged over
RISE_SMOOTH_S, first crossed 10, 20, ... 90 % of its own equilibrium, from the commanded
opening. The model is the simulated plant's own network of the same circuit
(drivers/sim/rise.py: tank at P0, the ISO valve, the hose as stated, the actuator on the
free P-V law just fitted with its dashpot, the sensor where the config puts it), sampled
at the rig's sample period and read by the same crossing function, so the averaging's
shift is in both. Per cycle, least squares of the crossing times against
``lag + T_f(C)`` in (lag, C); the critical ratio b is kept.

Why b is kept: from a tank at 150-165 kPa abs into an actuator at atmosphere the valve's
pressure ratio runs 0.6 -> 1, never choked for b below 0.6, and over that range a smaller
b with a larger C gives nearly the same elliptic flow curve: ln C and b correlate -0.998
in a fit of both. On the simulated plant (its model exact) the residual is lowest at the
plant's b but shallow: b 0.1 off costs 1-2 times the sensor's noise, while the fingers'
assumed lag 30 ms off costs 4 times (tests/system/test_characterise_iso.py), so on a rig
b would be fitted to what the model's stated parts get wrong. The fit states the
correlation its own Jacobian gives (3-parameter, at the top level) in its notes, and what
a b 0.1 off would do to C; C's interval takes b as exact.

What the rise cannot show, kept and said so: a rise over fewer than ISO_MIN_RISE_SAMPLES
samples (a polled box), a rise whose times move less with C than with the hose's stated
length (a long hose dominates: an error in it would move C by more than itself), a fit at the edge
of the searched range.
Refused: a residual far beyond the sensor's noise (ISO_RESIDUAL_NOISE) - the circuit is
not the model (a hose not as stated, a b far off, heat) and its C would be a number
fitted to the wrong shape.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from fluidsense.common.units import KPA, ML
from fluidsense.controller.config.profile import FittedNumber, Profile
from scipy import interpolate, optimize, stats

from .rise_trace import RISE_FRACTIONS, RISE_MIN_LEVEL, free_equilibrium, rise_crossings, smooth_width, smoothed

C_FIELD = "circuit.valve.sonic_conductance_dm3_per_s_bar"
B_FIELD = "circuit.valve.critical_ratio"
DELAY_FIELD = "circuit.valve_delay_s"
# The search: a coarse pass over 0.3-3.3 times the starting C (a catalogue figure, or an
# assumed one, is rarely off by more), then a fine grid around the coarse optimum that the
# per-cycle fits interpolate (cubic in ln C, ln t).
COARSE = np.geomspace(0.3, 3.3, 9)
_STEP = float(COARSE[1] / COARSE[0])
FINE = np.geomspace(1 / _STEP, _STEP, 9)  # from the coarse optimum's neighbour to its other neighbour
ISO_MIN_RISE_SAMPLES = 20  # samples from 10 to 90 %: fewer and the shape is the sample period's
HOSE_STEP = 1.05  # the hose's length changed by this to see how much it sets the rise
ISO_RESIDUAL_NOISE = 5.0  # rms pressure residual of the rise beyond this many sensor-noise sd: refused
T_END_FACTOR = 2.5  # the model runs this many times the rig's slowest 90 % crossing (coarse C can be slow)


@dataclass
class IsoRise:
    fitted: list[FittedNumber] = field(default_factory=list)
    measured: list[FittedNumber] = field(default_factory=list)
    kept: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    refused: list[str] = field(default_factory=list)
    per_cycle: list[dict[str, float]] = field(default_factory=list)  # (level, lag, C, residuals): tests print them


def _hw(start: Profile, v0_ml: float, c_ml_kpa: float, cond: float, b: float | None = None):
    """The starting profile's hardware with the fitted actuator and a candidate valve."""
    hw = start.hardware
    valve = hw.circuit.valve.model_copy(update={"sonic_conductance_dm3_per_s_bar": cond,
                                                **({} if b is None else {"critical_ratio": b})})
    act = hw.actuator.model_copy(update={"v0_ml": v0_ml, "compliance_ml_per_kpa": c_ml_kpa})
    return hw.model_copy(update={"circuit": hw.circuit.model_copy(update={"valve": valve}), "actuator": act})


def _longer_hose(start: Profile, factor: float) -> Profile:
    h = start.circuit.hose
    return start.model_copy(update={"circuit": start.circuit.model_copy(
        update={"hose": h.model_copy(update={"length_m": h.length_m * factor})})})


def _model_times(hw, p0: float, level: float, dt: float, t_end: float) -> np.ndarray | None:
    """The plant's crossing times (s from the opening) for a tank at ``p0``, at fractions
    of its own equilibrium ``level`` (both Pa, oriented upwards as the rig's are)."""
    # imported when used: a characterisation that fits no ISO valve never loads the simulator
    from fluidsense.drivers.sim.rise import free_rise

    t, p = free_rise(hw, p0, t_end, dt)
    sign = 1.0 if level >= 0 else -1.0
    times = rise_crossings(t, smoothed(sign * p, smooth_width(dt)), abs(level))
    return None if times is None else np.asarray(times)


class _Level:
    """One P0 level's model: crossing times against ln C on a grid, interpolated."""

    def __init__(self, start: Profile, v0_ml: float, c_ml_kpa: float, p0: float, dt: float, t_end: float,
                 v_side: float, c_si: float):
        self.start, self.v0_ml, self.c_ml_kpa, self.p0, self.dt, self.t_end = start, v0_ml, c_ml_kpa, p0, dt, t_end
        c = start.circuit
        self.level = float(free_equilibrium(p0, c.tank_m3, v_side, c_si, c.p_atm))
        self.spline = None

    def times(self, cond: float, b: float | None = None) -> np.ndarray | None:
        return _model_times(_hw(self.start, self.v0_ml, self.c_ml_kpa, cond, b), self.p0, self.level, self.dt,
                            self.t_end)

    def grid(self, conds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rows = [(c, self.times(float(c))) for c in conds]
        ok = [(c, t) for c, t in rows if t is not None]
        return np.log([c for c, _ in ok]), np.array([t for _, t in ok])

    def fit_spline(self, conds: np.ndarray) -> None:
        x, tt = self.grid(conds)
        self.spline = None
        if x.size >= 4:
            self.lo, self.hi = float(x.min()), float(x.max())
            self.spline = interpolate.CubicSpline(x, np.log(tt), axis=0)

    def at(self, ln_c: float) -> np.ndarray:
        return np.exp(self.spline(ln_c))


def _fit_cycle(times: np.ndarray, model: _Level) -> tuple[float, float, float]:
    """(lag s, ln C, rms time residual s) of one rise: the lag is the mean offset at each C
    (linear in it), ln C by a bounded search on the model's spline."""
    def ssr(x: float) -> float:
        r = times - model.at(x)
        r = r - r.mean()
        return float(r @ r)

    res = optimize.minimize_scalar(ssr, bounds=(model.lo, model.hi), method="bounded",
                                   options={"xatol": 1e-6})
    lag = float(np.mean(times - model.at(res.x)))
    return lag, float(res.x), math.sqrt(ssr(res.x) / times.size)


def _t95(dof: int) -> float:
    return float(stats.t.ppf(0.975, max(dof, 1)))


def fit_iso_valve(entries: Sequence[dict[str, Any]], start: Profile, v_side_ml: float, c_fit: float,
                  fixed_ml: float, cov: np.ndarray, noise_kpa: float) -> IsoRise:
    """C (and the valve's delay with it) from the rises at levels from RISE_MIN_LEVEL of
    the top one, or the reasons it is kept or refused. ``v_side_ml``/``c_fit``/``cov``: the
    free P-V fit (side volume incl. ``fixed_ml`` of hose and ports, ml and ml/kPa)."""
    out = IsoRise()
    valve = start.circuit.valve
    c0, b0 = float(valve.sonic_conductance_dm3_per_s_bar), float(valve.critical_ratio)
    top = max(abs(e["level_kpa"]) for e in entries)
    used = [e for e in entries if e["rise_t_s"] is not None and abs(e["level_kpa"]) >= RISE_MIN_LEVEL * top]
    dts = [e["dt_s"] for e in used if e.get("dt_s")]

    def keep(why: str) -> IsoRise:
        for name in (C_FIELD, B_FIELD, DELAY_FIELD):
            out.kept[name] = why
        return out

    if len(used) < 2:
        return keep("too few rises recorded to fit the valve")
    if len(dts) < len(used):
        return keep("the journal does not hold the traces' sample period (written by an older fluidsense): "
                    "the rise cannot be modelled at it")
    dt = float(np.median(dts))
    span = float(np.median([e["rise_t_s"][-1] - e["rise_t_s"][0] for e in used]))
    if span / dt < ISO_MIN_RISE_SAMPLES:
        return keep(f"the rise from 10 to 90 % takes {1e3 * span:.3g} ms, {span / dt:.1f} samples at the "
                    f"{1e3 * dt:.3g} ms sample period (fewer than {ISO_MIN_RISE_SAMPLES}): its shape is the "
                    "sampling's, not the valve's")
    t_end = T_END_FACTOR * max(e["rise_t_s"][-1] for e in used) + 0.05

    def levels_for(v_side: float, c_ml: float) -> dict[float, _Level]:
        return {lv: _Level(start, v_side - fixed_ml, c_ml, lv * KPA, dt, t_end, v_side * ML, c_ml * ML / KPA)
                for lv in sorted({e["level_kpa"] for e in used})}

    def per_cycle(models: dict[float, _Level]) -> list[tuple[float, float, float]]:
        return [_fit_cycle(np.asarray(e["rise_t_s"]), models[e["level_kpa"]]) for e in used]

    # locate: the coarse grid at the top level, the mean rise there
    models = levels_for(v_side_ml, c_fit)
    top_lv = max(models, key=abs)
    t_top = np.mean([e["rise_t_s"] for e in used if e["level_kpa"] == top_lv], axis=0)
    coarse = []
    for k in COARSE:
        m = models[top_lv].times(c0 * float(k))
        if m is not None:
            r = t_top - m
            coarse.append((float(((r - r.mean()) ** 2).sum()), c0 * float(k)))
    if not coarse:
        return keep(f"the modelled rise did not reach 90 % within {t_end:.3g} s for any C from "
                    f"{COARSE[0]:g} to {COARSE[-1]:g} times the starting {c0:g}")
    c_best = min(coarse)[1]
    if c_best in (c0 * COARSE[0], c0 * COARSE[-1]):
        return keep(f"the rise is best matched at the edge of the searched C ({c_best:.3g} dm^3/(s bar), "
                    f"{COARSE[0]:g}-{COARSE[-1]:g} x the starting {c0:g}): the valve is not the one stated, or "
                    "something else sets the rise")
    for m in models.values():
        m.fit_spline(c_best * FINE)
        if m.spline is None:
            return keep("the modelled rise did not reach 90 % near the best C")
    # does C show? how far the top level's crossing times move per unit of ln C, against
    # how far they move with the stated hose's length (its volume and friction, the level
    # its own): where the hose moves them more, it dominates the rise, and an error in the
    # stated hose moves C by more than itself
    sens = float(np.median(np.abs(models[top_lv].spline(math.log(c_best), 1))))
    if start.circuit.hose is not None:
        extra = start.circuit.hose.volume_m3 * (HOSE_STEP - 1) / ML
        longer = _Level(_longer_hose(start, HOSE_STEP), v_side_ml - fixed_ml, c_fit, top_lv * KPA, dt, t_end,
                        (v_side_ml + extra) * ML, c_fit * ML / KPA)
        t_base, t_long = models[top_lv].times(c_best), longer.times(c_best)
        if t_base is None or t_long is None:
            return keep("the modelled rise with a longer hose did not reach 90 %")
        sens_hose = float(np.median(np.abs(np.log(t_long / t_base)))) / math.log(HOSE_STEP)
        out.notes.append(f"ISO valve: the rise's times move {sens:.2f} % per % of C and {sens_hose:.2f} % per % "
                         "of the hose's stated length")
        if sens < sens_hose:
            return keep(f"the hose dominates the rise: its times move {sens:.2f} % per % of C and {sens_hose:.2f} "
                        "% per % of the hose's stated length, so an error in the stated hose would move C by more "
                        "than itself")
    fits = per_cycle(models)
    lags = np.array([f[0] for f in fits])
    ln_cs = np.array([f[1] for f in fits])
    at_edge = [f for e, f in zip(used, fits)
               if min(abs(f[1] - models[e["level_kpa"]].lo), abs(f[1] - models[e["level_kpa"]].hi)) < 1e-3]
    if at_edge:
        return keep(f"{len(at_edge)} rise(s) fitted at the edge of the fine grid ({1 / _STEP:.2f}-{_STEP:.2f} x "
                    f"{c_best:.3g}): "
                    "the rises disagree more than the grid spans")
    # the residual in pressure: each crossing's time residual times the rise's slope there
    p_res = []
    for e, (lag, x, _) in zip(used, fits):
        m = models[e["level_kpa"]]
        mt = m.at(x)
        slope = np.gradient(np.asarray(RISE_FRACTIONS) * abs(m.level), mt)
        p_res.append((np.asarray(e["rise_t_s"]) - lag - mt) * slope)
    p_res = np.asarray(p_res)
    rms_p = float(np.sqrt(np.mean(p_res**2))) / KPA
    rms_t = float(np.sqrt(np.mean([f[2] ** 2 for f in fits])))
    for e, (lag, x, rt), pr in zip(used, fits, p_res):
        out.per_cycle.append({"level_kpa": e["level_kpa"], "lag_s": lag, "c": math.exp(x), "rms_t_s": rt,
                              "rms_kpa": float(np.sqrt(np.mean(pr**2))) / KPA})
    out.notes.append(f"ISO valve rise fit: rms residual {1e3 * rms_t:.3g} ms over the 10-90 % crossings, "
                     f"{rms_p:.3g} kPa in pressure (sensor noise {noise_kpa:.3g} kPa)")
    if rms_p > ISO_RESIDUAL_NOISE * noise_kpa:
        out.refused.append(f"the rise does not follow the ISO 6358 valve's model: its residual is {rms_p:.3g} kPa "
                           f"rms, {rms_p / noise_kpa:.0f} times the sensor's noise ({noise_kpa:.3g} kPa; refused "
                           f"beyond {ISO_RESIDUAL_NOISE:g}): a hose not as stated, a critical ratio far from "
                           f"{b0:g}, or a circuit that is not the config's")

    # the fitted volumes' uncertainty: the mean ln C's gradient in (v_side, c) by central
    # differences of one standard error each, carried through their covariance
    se = np.sqrt(np.diag(cov))
    grad_c, grad_l = np.zeros(2), np.zeros(2)
    for i in range(2):
        means = []
        for s in (1.0, -1.0):
            x = np.array([v_side_ml, c_fit]) + s * se[i] * np.eye(2)[i]
            mods = levels_for(float(x[0]), float(x[1]))
            for m in mods.values():
                m.fit_spline(c_best * FINE)
            f = per_cycle(mods)
            means.append((np.mean([g[1] for g in f]), np.mean([g[0] for g in f])))
        grad_c[i] = (means[0][0] - means[1][0]) / (2 * se[i])
        grad_l[i] = (means[0][1] - means[1][1]) / (2 * se[i])
    var_vol_c, var_vol_l = float(grad_c @ cov @ grad_c), float(grad_l @ cov @ grad_l)

    n = len(fits)
    t95 = _t95(n - 1)

    def interval(x: np.ndarray, var_vol: float) -> tuple[float, float]:
        m = float(x.mean())
        h = math.sqrt((t95 * float(x.std(ddof=1)) / math.sqrt(n)) ** 2 + 1.96**2 * var_vol)
        return m, h

    m_ln, h_ln = interval(ln_cs, var_vol_c)
    m_lag, h_lag = interval(lags, var_vol_l)
    cond = math.exp(m_ln)
    levels_words = ", ".join(f"{lv:g}" for lv in sorted(models))
    out.fitted.append(FittedNumber(
        field=C_FIELD, value=cond, lo95=math.exp(m_ln - h_ln), hi95=math.exp(m_ln + h_ln), unit="dm^3/(s bar)",
        how=f"least squares of {n} rises (P0 {levels_words} kPa; the 10-90 % crossings of the trace averaged over "
            f"{smooth_width(dt)} samples, after the fitted delay below) against the simulated plant's network of "
            "this circuit (the ISO 6358 valve, the stated hose and tank, the fitted free P-V law, the kept "
            f"actuator lag), one C per rise; critical ratio {b0:g} kept; geometric mean, 95 % interval from the "
            "rises' spread (Student's t on ln C) and the fitted volumes' covariance. Not in the interval: what the "
            "model takes as stated (the critical ratio, the actuator's response_s, the hose's bore and length): "
            "their errors move C outside it (notes)"))
    out.fitted.append(FittedNumber(
        field=DELAY_FIELD, value=max(m_lag, 0.0), lo95=max(m_lag - h_lag, 0.0), hi95=max(m_lag + h_lag, 0.0),
        unit="s", how=f"mean over {n} rises of the lag fitted with C above (the offset of the plant's rise from "
                      "the commanded opening, with the command path's latency); interval as C's"))
    # b against C: the 3-parameter Jacobian of the top level's mean rise at the fit
    m = models[top_lv]
    base = m.times(cond)
    dl, db = 0.02, 0.02
    tc, tb = m.times(cond * math.exp(dl)), m.times(cond, min(b0 + db, 0.95))
    if base is not None and tc is not None and tb is not None:
        jac = np.column_stack([np.ones_like(base), (tc - base) / dl, (tb - base) / (min(b0 + db, 0.95) - b0)])
        cv = np.linalg.inv(jac.T @ jac)
        corr = cv[1, 2] / math.sqrt(cv[1, 1] * cv[2, 2])
        # what a b off by 0.1 does to the fitted C: the b column regressed on (lag, ln C)
        coef, *_ = np.linalg.lstsq(jac[:, :2], jac[:, 2], rcond=None)
        shift = 100 * (math.exp(-coef[1] * 0.1) - 1)
        out.notes.append(f"ISO valve: correlation of ln C and b in a (lag, C, b) fit of the rise: {corr:+.4f}; "
                         f"a critical ratio 0.1 above the kept {b0:g} would fit a C {shift:+.1f} % off "
                         "(C's interval takes b as exact)")
        out.kept[B_FIELD] = (f"the rise cannot separate it from C (their correlation in a fit of both: "
                             f"{corr:+.4f}; the valve's pressure ratio runs from "
                             f"{(start.circuit.p_atm) / (start.circuit.p_atm + top_lv * KPA):.2f} to 1): kept, "
                             f"and C is fitted for it (a b 0.1 higher would give a C {shift:+.1f} % off)")
    else:
        out.kept[B_FIELD] = "the rise cannot separate it from C: kept, and C is fitted for it"
    return out
