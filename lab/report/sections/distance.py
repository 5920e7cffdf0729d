"""Distance to a plate (the paper's supplementary "Distance sensing with PneuNet bending actuator"): the three supply methods, calibration on a height sweep, accuracy on held-out heights."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from fluidsense.common.scenes import (
    EmptyScene,
    PlateScene,
)
from fluidsense.common.units import KPA, LITRE, ML, P_ATM
from fluidsense.simulator.actuators import volume_law
from fluidsense.simulator.equilibrium import equilibrium
from fluidsense.tasks.experiments import reference, sweep
from scipy import stats

from ..common import (
    Section,
    errors_on,
    fit,
    img,
    interval95,
    profile,
    r4,
    run_on,
)
from ..plots import figure, save

HEIGHTS = [0, 5, 10, 15, 20, 25, 30, 35, 40]
PAPER_ACCURACY = {"tank": (-1.7, 1.7), "pressure_flow": (-4.7, 4.7), "flow_control": (-3.4, 3.4),
                  "t_c": (-2.9, 3.8)}


def _held_out_heights(seed: int, n: int = 30) -> list[float]:
    rng = np.random.default_rng(seed)
    out: list[float] = []
    while len(out) < n:
        h = float(rng.uniform(0.5, 39.5))
        if abs(h - round(h / 5) * 5) > 0.5:  # never a calibration height
            out.append(round(h, 2))
    return out


def _accuracy_rows(sec: Section, key: str, label: str, err: np.ndarray, source: str) -> tuple[float, float]:
    lo, hi = interval95(err)
    p_lo, p_hi = PAPER_ACCURACY[key]
    ours_half, paper_half = (hi - lo) / 2, (p_hi - p_lo) / 2
    # a 95 % interval from about 50 readings carries roughly 20 % sampling error
    ok = abs(ours_half - paper_half) <= 0.25 * paper_half
    if ok:
        why = ""
    elif ours_half < paper_half and key == "t_c":
        why = ("in the model contact is a sharp kink of the volume law; a real tip touches gradually, "
               "which widens the paper's interval")
    elif ours_half < paper_half:
        why = ("in the calibration's own session the parts' per-session errors (regulator setpoint, flow "
               "controller accuracy) are common to calibration and test and cancel; the fresh-session row "
               "carries them")
    else:
        why = "our model's noise at this method is larger than the paper's"
    sec.row(f"distance accuracy, {label} (95 % of predicted - true, held-out heights in the calibration's "
            f"session)", f"{p_lo:+.1f} to {p_hi:+.1f} mm",
            f"{lo:+.2f} to {hi:+.2f} mm", ok, why, source, kind="predicted",
            figures=(f"{p_lo:+.1f} mm", f"{p_hi:+.1f} mm"),
            tolerance="half-width within 25 % of the paper's (sampling error of a 95 % interval)")
    return lo, hi


def _budget_row(sec: Section, key: str, label: str) -> dict:
    """The method's 95 % accuracy predicted from its parts' figures over fresh sessions
    (``python -m lab bench budget``: static plant, 40 calibrations x 50 held-out sessions)."""
    from lab.bench.budget import SOURCES, predict

    pred = predict(key, n_cal=40, n_test=50, seed=1)
    alone = {src: predict(key, 20, 25, 1, frozenset({src}))["abs_error_95_mm"] for src in SOURCES}
    top = max(alone, key=alone.get)
    p_half = PAPER_ACCURACY[key][1]
    ours = pred["abs_error_95_mm"]
    ok = abs(ours - p_half) <= 0.25 * p_half
    why = "" if ok else (f"the largest part is the {top}, {alone[top]:.2f} mm alone (figures and their status: "
                         "simulator/parts.py); a mismatch stays one, no figure is set from it")
    sec.row(f"distance accuracy, {label}, predicted from the parts' figures (fresh sessions)",
            f"+-{p_half:.1f} mm", f"+-{ours:.2f} mm over {pred['trials']} held-out sessions; intervals cover "
            f"{100 * pred['coverage95']:.0f} % ({100 * pred['coverage95_own_session_only']:.0f} % without the "
            "session term)", ok, why, "Fig. S sensing accuracy", kind="predicted", figures=(f"{p_half:.1f} mm",),
            tolerance="within 25 % of the paper's half-width (the goal; the 95th percentile of 2000 trials "
            "carries about 2 % sampling error)")
    return {"budget_err95_mm": round(ours, 3), "budget_coverage95": round(pred["coverage95"], 3),
            "budget_coverage95_own_session_only": round(pred["coverage95_own_session_only"], 3),
            "budget_alone_mm": {k: round(v, 3) for k, v in alone.items()}}


def _distance(key: str, profile_name: str, feature: str, label: str, fit_kind: str, seed: int, out: Path,
              with_tc: bool = False) -> Section:
    prof = profile(profile_name)
    sec = Section(f"distance_{key}", f"Distance sensing: {label}")
    held = _held_out_heights(seed + 7)

    async def body(port):
        if with_tc:
            await reference(port)
        cal_runs = await sweep(port, PlateScene(height_mm=0), "height_mm", HEIGHTS, cycles=8, drop_first=1)
        test_runs = await sweep(port, PlateScene(height_mm=0), "height_mm", held, cycles=1)
        return cal_runs, test_runs

    cal_runs, test_runs = run_on(prof, body, seed)
    unit = "ml" if feature == "v_eq" else "kPa"
    cal = fit(cal_runs, feature, fit_kind, target="height_mm", target_unit="mm")
    err = errors_on(cal, test_runs, feature)
    lo, hi = _accuracy_rows(sec, key, label, err, "Fig. 1b-d, Fig. S sensing accuracy")
    sec.numbers.update(_budget_row(sec, key, label))
    sec.numbers.update({"slope": r4(cal.slope), "slope_unit": f"{unit}/mm", "residual_sd": r4(cal.residual_sd),
                        "err95_lo_mm": r4(lo), "err95_hi_mm": r4(hi), "calibration_cycles": len(cal.x),
                        "held_out_cycles": len(test_runs)})
    fig, ax = figure(2, 1)
    x = np.array([r.target for r in cal_runs])
    y = np.array([r.result.p_eq / KPA if feature == "p_eq" else r.result.v_eq * 1e6 for r in cal_runs])
    ax[0, 0].plot(x, y, ".", alpha=0.5, label="calibration cycles")
    xs = np.linspace(0, 40, 100)
    ax[0, 0].plot(xs, cal.predict(xs), "-", label=f"{fit_kind} fit")
    ax[0, 0].set_xlabel("plate height h (mm)")
    ax[0, 0].set_ylabel("P_eq (kPa)" if feature == "p_eq" else "V_eq (standard ml)")
    ax[0, 0].legend()
    ax[0, 1].hist(err[np.isfinite(err)], bins=15)
    ax[0, 1].axvspan(*PAPER_ACCURACY[key], alpha=0.15, color="k", label="paper 95 %")
    ax[0, 1].axvline(lo, color="r", ls="--")
    ax[0, 1].axvline(hi, color="r", ls="--", label="ours 95 %")
    ax[0, 1].set_xlabel("predicted - true h (mm), held-out heights")
    ax[0, 1].legend()
    name = save(fig, out, f"distance_{key}.png")
    text = [f"Profile `{prof.name}`: {prof.description}. Calibration: h = 0..40 mm in 5 mm steps, 8 cycles "
            f"each, the first dropped (paper protocol); test: {len(held)} single cycles at heights drawn "
            f"uniformly and never equal to a calibration height.",
            "", img(name, label), "",
            f"Fit: {cal.slope:.4g} {unit}/mm, residual sd {cal.residual_sd:.3g} {unit}; 95 % of the held-out "
            f"errors within {lo:+.2f} .. {hi:+.2f} mm (paper {PAPER_ACCURACY[key][0]:+.1f} .. "
            f"{PAPER_ACCURACY[key][1]:+.1f} mm)."]
    if key == "tank":
        sec.row("average distance resolution, tank method", "about 0.04 kPa/mm", f"{abs(cal.slope):.4f} kPa/mm",
                abs(abs(cal.slope) - 0.04) <= 0.005, "bending actuator defaults derived from it (docs/physics.md)",
                "Results; Methods, distance sensing", kind="fitted", parameter="contact_ratio",
                set_from=("0.04 kPa/mm",), figures=("0.04 kPa/mm",), tolerance="+-0.005 kPa/mm (last digit given)")
    if with_tc:
        tc_cal = fit(cal_runs, "t_c_slope", "poly2", target="height_mm", target_unit="mm")
        tc_err = errors_on(tc_cal, test_runs, "t_c_slope")
        tlo, thi = _accuracy_rows(sec, "t_c", "time of first contact", tc_err, "Fig. 2c, Fig. S sensing accuracy")
        sec.numbers.update({"t_c_err95_lo_mm": r4(tlo), "t_c_err95_hi_mm": r4(thi)})
        # the force a load cell under the plate would read (the plant's own state at the
        # window), never one computed from the measured P_eq
        force = np.array([r.truth["tip_force_n"] for r in cal_runs])
        pe = np.array([r.result.p_eq / KPA for r in cal_runs])
        fl = stats.linregress(pe, force)
        sec.numbers.update({"force_slope_n_per_kpa": r4(fl.slope), "force_r2": r4(fl.rvalue**2)})
        sec.row("force on the plate inferred from P_eq", "linear (Fig. S force calibration)",
                f"F = {fl.slope:.3g} N/kPa x P_eq {fl.intercept:+.3g} N, r^2 {fl.rvalue ** 2:.3f}", None,
                "force area of the tip is assumed (docs/physics.md)", "Results, Fig. S force calibration",
                kind="predicted")
        tc = np.array([r.result.t_c_slope for r in cal_runs])
        fig, ax = figure(2, 1)
        ax[0, 0].plot(x, tc, ".", alpha=0.5)
        ax[0, 0].plot(xs, tc_cal.predict(xs), "-")
        ax[0, 0].set_xlabel("plate height h (mm)")
        ax[0, 0].set_ylabel("t_c1 (s after opening)")
        ax[0, 1].plot(pe, force, ".", alpha=0.5)
        ax[0, 1].set_xlabel("P_eq (kPa)")
        ax[0, 1].set_ylabel("tip force (N)")
        name2 = save(fig, out, "distance_tc_force.png")
        text += ["", f"Time of first contact from the same cycles (dP against a free-air reference, change of "
                 f"slope): quadratic fit of t_c against h; 95 % of the held-out errors within {tlo:+.2f} .. "
                 f"{thi:+.2f} mm (paper -2.9 .. +3.8 mm). The force on the plate (the model's tip force) is "
                 f"linear in P_eq (r^2 {fl.rvalue ** 2:.3f}).", "", img(name2, "t_c and force")]
        # tank volume tunes the resolution (Fig. S resolution 2 caps): the static model
        slopes = {}
        for tank in (0.1, 0.3):
            p = [equilibrium(prof.sequence.p0_pa, tank * LITRE, volume_law(prof.actuator, PlateScene(height_mm=h),
                                                                            P_ATM), P_ATM) for h in (0, 40)]
            slopes[tank] = (p[1] - p[0]) / 40 / KPA
        sec.numbers["slope_by_tank_kpa_per_mm"] = {str(k): r4(v) for k, v in slopes.items()}
        sec.row("tank volume tunes the resolution (0.1 vs 0.3 L)", "different h-pressure slopes",
                f"{slopes[0.1]:.4f} vs {slopes[0.3]:.4f} kPa/mm", None, "eq. 1-2: v_tank enters both terms",
                "Fig. S resolution 2 caps", kind="predicted")
        # free-actuation air volume (Fig. 1a snapshot at 28.7 ml input)
        law = volume_law(prof.actuator, EmptyScene(), P_ATM)
        p1 = equilibrium(prof.sequence.p0_pa, prof.circuit.tank_m3, law, P_ATM)
        v_std = ((p1 + P_ATM) * float(law.volume_at(p1)) - P_ATM * prof.actuator.v0) / P_ATM / ML
        sec.numbers["free_standard_volume_ml"] = r4(v_std)
        sec.row("air in the free actuator at the tank equilibrium", "28.7 ml (snapshot)", f"{v_std:.1f} ml",
                abs(v_std - 28.7) < 3, "v0 and compliance chosen with it", "Fig. 1a",
                kind="fitted", parameter="v0, compliance", set_from=("28.7 ml",), figures=("28.7 ml",),
                tolerance="+-3 ml (reading error of a snapshot in a figure)")
    sec.markdown = "\n".join(text)
    return sec


def distance_tank(out: Path, seed: int) -> Section:
    return _distance("tank", "pneunet-bending", "p_eq", "tank + valve, P_eq (method 1)", "linear", seed, out,
                     with_tc=True)


def distance_pressure_flow(out: Path, seed: int) -> Section:
    return _distance("pressure_flow", "pneunet-bending-pressure-flow", "v_eq",
                     "pressure control + flow measurement, V_eq (method 2)", "linear", seed, out)


def distance_flow_control(out: Path, seed: int) -> Section:
    return _distance("flow_control", "pneunet-bending-flow-control", "p_eq",
                     "flow control + pressure measurement, P_eq (method 3)", "linear", seed, out)
