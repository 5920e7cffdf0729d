"""Sections of the reproduction report, one per experiment of the paper.

Each function runs its experiment on the simulated cell (virtual time, fixed seeds),
draws its figures into ``out`` and returns a Section: Markdown, numbers, and rows of the
paper-versus-ours table. Sections are independent, so they can run in parallel.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import stats

from common.hardware import BendingActuator
from common.scenes import (
    CylinderScene,
    EmptyScene,
    PlateScene,
    ProfileScene,
    PullScene,
    RectangleScene,
    SampleScene,
    StopperScene,
)
from common.units import KPA, LITRE, ML, P_ATM
from controller.cycles import features as F
from simulator.actuators import contact_truth, volume_law
from simulator.equilibrium import eq2_resolution, equilibrium
from simulator.resolution import LINEAR_PARAMS, linear_sweep, search
from tasks.experiments import reference, sweep

from .common import Section, errors_on, fit, img, interval95, md_table, profile, r4, run_on
from .plots import figure, save

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
    ok = ours_half <= 1.5 * paper_half and ours_half >= paper_half / 3
    if ok:
        why = "same order as the paper"
    elif ours_half < paper_half and key == "t_c":
        why = ("in the model contact is a sharp kink of the volume law and the actuator has no inertia or "
               "viscoelastic lag; a real tip touches gradually, which widens the paper's interval")
    elif ours_half < paper_half:
        why = ("the simulated cell has only the noise and cycle-to-cycle variation we model; the real actuator "
               "adds hysteresis and creep")
    else:
        why = "our model's noise at this method is larger than the paper's"
    sec.row(f"distance accuracy, {label} (95 % of predicted - true)", f"{p_lo:+.1f} to {p_hi:+.1f} mm",
            f"{lo:+.2f} to {hi:+.2f} mm", ok, why, source)
    return lo, hi


def _distance(key: str, profile_name: str, feature: str, label: str, fit_kind: str, seed: int, out: Path,
              with_tc: bool = False) -> Section:
    prof = profile(profile_name)
    sec = Section(f"distance_{key}", f"Distance sensing: {label}")
    held = _held_out_heights(seed + 7)

    async def body(ctrl):
        if with_tc:
            await reference(ctrl)
        cal_runs = await sweep(ctrl, PlateScene(height_mm=0), "height_mm", HEIGHTS, cycles=8, drop_first=1)
        test_runs = await sweep(ctrl, PlateScene(height_mm=0), "height_mm", held, cycles=1)
        return cal_runs, test_runs

    cal_runs, test_runs = run_on(prof, body, seed)
    unit = "ml" if feature == "v_eq" else "kPa"
    cal = fit(cal_runs, feature, fit_kind, target="height_mm", target_unit="mm")
    err = errors_on(cal, test_runs, feature)
    lo, hi = _accuracy_rows(sec, key, label, err, "Fig. 1b-d, Fig. S sensing accuracy")
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
                abs(abs(cal.slope) - 0.04) < 0.01, "bending actuator defaults derived from it (docs/physics.md)",
                "Results; Methods, distance sensing")
    if with_tc:
        tc_cal = fit(cal_runs, "t_c_slope", "poly2", target="height_mm", target_unit="mm")
        tc_err = errors_on(tc_cal, test_runs, "t_c_slope")
        tlo, thi = _accuracy_rows(sec, "t_c", "time of first contact", tc_err, "Fig. 2c, Fig. S sensing accuracy")
        sec.numbers.update({"t_c_err95_lo_mm": r4(tlo), "t_c_err95_hi_mm": r4(thi)})
        force = np.array([contact_truth(prof.actuator, r.scene, P_ATM, r.result.p_eq)["tip_force_n"]
                          for r in cal_runs])
        pe = np.array([r.result.p_eq / KPA for r in cal_runs])
        fl = stats.linregress(pe, force)
        sec.numbers.update({"force_slope_n_per_kpa": r4(fl.slope), "force_r2": r4(fl.rvalue**2)})
        sec.row("force on the plate inferred from P_eq", "linear (Fig. S force calibration)",
                f"F = {fl.slope:.3g} N/kPa x P_eq {fl.intercept:+.3g} N, r^2 {fl.rvalue ** 2:.3f}", None,
                "force area of the tip is assumed (docs/physics.md)", "Results, Fig. S force calibration")
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
                "Fig. S resolution 2 caps")
        # free-actuation air volume (Fig. 1a snapshot at 28.7 ml input)
        law = volume_law(prof.actuator, EmptyScene(), P_ATM)
        p1 = equilibrium(prof.sequence.p0_pa, prof.circuit.tank_m3, law, P_ATM)
        v_std = ((p1 + P_ATM) * float(law.volume_at(p1)) - P_ATM * prof.actuator.v0) / P_ATM / ML
        sec.numbers["free_standard_volume_ml"] = r4(v_std)
        sec.row("air in the free actuator at the tank equilibrium", "28.7 ml (snapshot)", f"{v_std:.1f} ml",
                abs(v_std - 28.7) < 3, "v0 and compliance chosen with it", "Fig. 1a")
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


def gripper(out: Path, seed: int) -> Section:
    prof = profile("pneunet-gripper")
    sec = Section("gripper", "Size sensing with the four-finger gripper")
    objects = [EmptyScene()] + [CylinderScene(diameter_mm=d) for d in (20, 40, 60, 80, 100)]

    async def body(ctrl):
        size = await sweep(ctrl, None, None, objects, cycles=6, drop_first=1)
        cyc_empty = await sweep(ctrl, None, None, [EmptyScene()], cycles=111)
        cyc_80 = await sweep(ctrl, None, None, [CylinderScene(diameter_mm=80)], cycles=111)
        return size, cyc_empty, cyc_80

    size, cyc_empty, cyc_80 = run_on(prof, body, seed)
    table, means = [], {}
    for obj in objects:
        vals = np.array([r.result.p_eq for r in size if r.scene == obj]) / KPA
        d = getattr(obj, "diameter_mm", None)
        means[d] = vals.mean()
        table.append(["nothing" if d is None else f"{d:g} mm", vals.mean(), vals.std(ddof=1)])
    ds = [40, 60, 80, 100]
    lr = stats.linregress(ds, [means[d] for d in ds])
    e, c80 = (np.array([r.result.p_eq for r in runs]) / KPA for runs in (cyc_empty, cyc_80))
    within = np.mean([r.result.p_sd for r in size]) / KPA
    sec.numbers.update({"p_eq_kpa": {str(k): r4(v) for k, v in means.items()}, "slope_kpa_per_mm": r4(lr.slope),
                        "r2": r4(lr.rvalue**2), "cycling_empty_mean": r4(e.mean()), "cycling_empty_95": r4(1.96 * e.std(ddof=1)),
                        "cycling_80_mean": r4(c80.mean()), "cycling_80_95": r4(1.96 * c80.std(ddof=1)),
                        "within_window_sd_kpa": r4(within)})
    sec.row("gripper P_eq slope over D = 40-100 mm", "about 0.04 kPa/mm, linear", f"{lr.slope:.4f} kPa/mm, r^2 {lr.rvalue ** 2:.4f}",
            abs(lr.slope - 0.04) < 0.008, "model built from Table S1's dv1/dD", "Fig. 1f; Table S1")
    sec.row("D = 20 mm barely touching", "curve almost equals the empty grip",
            f"{means[20] - means[None]:+.3f} kPa from empty", abs(means[20] - means[None]) < 0.2, "", "Fig. 1f")
    sec.row("empty grip, cycling test (111 cycles)", "34.5951 +- 0.0824 kPa (95 %)",
            f"{e.mean():.4f} +- {1.96 * e.std(ddof=1):.4f} kPa", abs(e.mean() - 34.6) < 0.15,
            "regulator repeatability set from this figure", "Fig. S cycling")
    sec.row("80 mm cylinder, cycling test", "35.4834 +- 0.0706 kPa (95 %)",
            f"{c80.mean():.4f} +- {1.96 * c80.std(ddof=1):.4f} kPa", False,
            "the cycling test used a different gripper version (its 80 mm rise is 0.9 kPa, the Fig. 1f "
            "gripper's about 2.4 kPa); our model follows Fig. 1f and Table S1", "Fig. S cycling")
    sec.row("per-sample noise", "sd about 0.07 kPa", f"{within:.4f} kPa (window sd)", abs(within - 0.07) < 0.01,
            "sensor model default", "Fig. 4b readings")
    fig, ax = figure(2, 1)
    for obj in objects:
        r = next(x for x in size if x.scene == obj)
        t, p = r.result.trace
        ax[0, 0].plot(t, p / KPA, lw=0.8, label="nothing" if obj.kind == "none" else f"D {obj.diameter_mm:g}")
    ax[0, 0].set_xlim(0, 6)
    ax[0, 0].set_xlabel("time after opening (s)")
    ax[0, 0].set_ylabel("gripper pressure (kPa)")
    ax[0, 0].legend(fontsize=7)
    ax[0, 1].errorbar([20] + ds, [means[d] for d in [20] + ds], yerr=[t[2] for t in table[1:]], fmt="o")
    ax[0, 1].axhline(means[None], color="k", ls=":", label="nothing")
    xs = np.linspace(30, 110, 10)
    ax[0, 1].plot(xs, lr.intercept + lr.slope * xs, "-", label=f"{lr.slope:.4f} kPa/mm")
    ax[0, 1].set_xlabel("cylinder diameter D (mm)")
    ax[0, 1].set_ylabel("P_eq, 4-5 s (kPa)")
    ax[0, 1].legend()
    name = save(fig, out, "gripper_size.png")
    sec.markdown = "\n".join([
        f"Profile `{prof.name}`: {prof.description}. Six cycles per object, the last five used, P_eq over 4-5 s "
        "(the paper's protocol; this is `fluidsense demo`).", "", img(name, "gripper size sensing"), "",
        md_table(["object", "P_eq (kPa)", "sd (kPa)"], table), "",
        f"Fit over 40-100 mm: {lr.slope:.4f} kPa/mm (r^2 {lr.rvalue ** 2:.4f}). Cycling, 111 cycles each: empty "
        f"{e.mean():.4f} +- {1.96 * e.std(ddof=1):.4f} kPa, 80 mm {c80.mean():.4f} +- {1.96 * c80.std(ddof=1):.4f} kPa "
        "(95 %)."])
    return sec


def shape(out: Path, seed: int) -> Section:
    prof = profile("pneunet-gripper-shape")
    sec = Section("shape", "Shape sensing: two contact times on rectangles")
    cal_w, test_w = [40, 55, 70, 85], [50, 65, 80]

    async def body(ctrl):
        await reference(ctrl)
        cyl = await sweep(ctrl, CylinderScene(diameter_mm=40), "diameter_mm", [40, 55, 70, 85, 100], cycles=3,
                          drop_first=1)
        rect_cal = await sweep(ctrl, RectangleScene(width_mm=40), "width_mm", cal_w, cycles=3, drop_first=1)
        rect_test = await sweep(ctrl, RectangleScene(width_mm=40), "width_mm", test_w + [100], cycles=1)
        ref_trace = ctrl.cycles.references[round(prof.sequence.p0_kpa, 3)]
        return cyl, rect_cal, rect_test, ref_trace

    cyl, rect_cal, rect_test, ref = run_on(prof, body, seed)
    c_cal = fit(cyl, "t_c_slope", "poly2", target="diameter_mm", target_unit="mm")
    w_cal = fit(rect_cal, "t_c2", "poly2", target="width_mm", target_unit="mm")
    rows, ratios = [], []
    for r in rect_test:
        t1, t2 = r.result.t_c_slope, r.result.t_c2
        length = c_cal.invert(t1).estimate
        width = w_cal.invert(t2).estimate if t2 is not None else length
        ratios.append((r.target / 100.0, width / length))
        rows.append([f"{r.target:g} x 100 mm", t1, "none" if t2 is None else f"{t2:.3f}", length, width,
                     r.target / 100.0, width / length])
    err = np.array([b - a for a, b in ratios])
    sec.numbers.update({"aspect_ratio_abs_err_max": r4(float(np.abs(err).max())),
                        "t_c1_spread_s": r4(float(np.ptp([r.result.t_c_slope for r in rect_test])))})
    sec.row("two contact events on rectangles", "first and second contact give length and width",
            f"aspect ratio within {np.abs(err).max():.3f} of the truth on held-out widths", None,
            "our second contact is calibrated on rectangles of known width", "Fig. 2d-e")
    fig, ax = figure(1, 1, width=6)
    for r in rect_test:
        t, p = r.result.trace
        dp = F.smooth(np.nan_to_num(F.delta_p(t, p, ref.t_rel, ref.p)), 21) / KPA
        line, = ax[0, 0].plot(t, dp, lw=0.8, label=f"W {r.target:g} mm")
        for tc in (r.result.t_c_slope, r.result.t_c2):
            if tc is not None:
                ax[0, 0].axvline(tc, color=line.get_color(), ls=":", lw=0.8)
    ax[0, 0].set_xlim(0, 8)
    ax[0, 0].set_xlabel("time after opening (s)")
    ax[0, 0].set_ylabel("dP = P - P_ref (kPa)")
    ax[0, 0].legend()
    name = save(fig, out, "shape_rectangles.png")
    sec.markdown = "\n".join([
        f"Profile `{prof.name}`: {prof.description}. Rectangles 100 mm long; one finger pair meets the length "
        "first, the other the width later. The first contact is converted to a length with a t_c-D calibration on "
        "cylinders, the second to a width with a t_c2-W calibration on rectangles of 40, 55, 70, 85 mm; the table "
        "shows held-out widths. We use a 1.8e9 Pa*s/m^3 resistor here (the paper used the gripper's small one): "
        "with the small one both contacts fall within 0.2 s and the second kink drowns in the noise at 1 kHz.", "",
        img(name, "dP of rectangles"), "",
        md_table(["object", "t_c1 (s)", "t_c2 (s)", "length est (mm)", "width est (mm)", "true W/L", "est W/L"],
                 rows)])
    return sec


def stiffness(out: Path, seed: int) -> Section:
    prof = profile("pneunet-bending")
    sec = Section("stiffness", "Stiffness: soft against rigid plate")
    plates = [PlateScene(height_mm=5), PlateScene(height_mm=5, stiffness_n_per_mm=0.65),
              PlateScene(height_mm=5, stiffness_n_per_mm=0.3)]

    async def body(ctrl):
        await reference(ctrl)
        cal = await sweep(ctrl, PlateScene(height_mm=0), "height_mm", [0, 5, 10, 15, 20], cycles=3, drop_first=1)
        runs = await sweep(ctrl, None, None, plates, cycles=1)
        return cal, runs, ctrl.cycles.references[round(prof.sequence.p0_kpa, 3)]

    cal_runs, runs, ref = run_on(prof, body, seed)
    tc_cal = fit(cal_runs, "t_c_slope", "poly2", target="height_mm", target_unit="mm")
    pe_cal = fit(cal_runs, "p_eq", "linear", target="height_mm", target_unit="mm")
    rows = []
    for r in runs:
        h_c = tc_cal.invert(r.result.t_c_slope).estimate
        h_e = pe_cal.invert(r.result.p_eq / KPA).estimate
        truth = contact_truth(BendingActuator(), r.scene, P_ATM, r.result.p_eq)
        k = r.scene.stiffness_n_per_mm
        rows.append(["rigid" if k is None else f"{k:g} N/mm", r.result.t_c_slope, h_c, r.result.p_eq / KPA, h_e,
                     h_e - h_c, truth["indentation_mm"]])
    dent = [row[5] for row in rows]
    ranked = dent[0] < dent[1] < dent[2]
    sec.numbers.update({"indentation_est_mm": [r4(x) for x in dent], "ranked": ranked})
    sec.row("stiffness ranking from t_c and P_eq", "softer plate: same t_c, lower P_eq, larger indentation",
            "ranked correctly" if ranked else "ranking wrong", ranked, "", "Fig. 2f-g")
    fig, ax = figure(1, 1, width=6)
    for r, row in zip(runs, rows):
        t, p = r.result.trace
        ax[0, 0].plot(t, F.smooth(np.nan_to_num(F.delta_p(t, p, ref.t_rel, ref.p)), 21) / KPA, lw=0.8,
                      label=row[0])
    ax[0, 0].set_xlabel("time after opening (s)")
    ax[0, 0].set_ylabel("dP (kPa)")
    ax[0, 0].legend()
    name = save(fig, out, "stiffness.png")
    sec.markdown = "\n".join([
        "The bending actuator 5 mm above a rigid plate and two soft ones. t_c gives the height where the tip "
        "first touched (t_c-h calibration on rigid plates), P_eq the height where it came to rest (P_eq-h "
        "calibration); the difference is the indentation, which ranks the stiffness.", "",
        img(name, "dP on soft and rigid plates"), "",
        md_table(["plate", "t_c (s)", "h from t_c (mm)", "P_eq (kPa)", "h from P_eq (mm)", "indentation est (mm)",
                  "indentation true (mm)"], rows)])
    return sec


def profile_scan(out: Path, seed: int) -> Section:
    prof = profile("pneunet-bending-scan")
    sec = Section("profile", "Profile scanning")
    seq = prof.sequence
    start = seq.charge_s + seq.isolate_s + 60.0  # the arm starts 60 s after the valve opens
    shapes = [ProfileScene(shape=s, base_mm=12.0, amplitude_mm=8.0, period_mm=25.0, delay_s=start)
              for s in ("sine", "triangle")]

    async def body(ctrl):
        await reference(ctrl)
        cal = await sweep(ctrl, PlateScene(height_mm=0), "height_mm", [0, 2, 4, 6, 8, 10, 12, 14], cycles=2,
                          drop_first=1)
        scans = await sweep(ctrl, None, None, shapes, cycles=1)
        return cal, scans, ctrl.cycles.references[round(seq.p0_kpa, 3)]

    cal_runs, scans, ref = run_on(prof, body, seed)
    cal = fit(cal_runs, "dp_eq", "poly2", target="height_mm", target_unit="mm")
    fig, ax = figure(1, 2, width=7, height=2.8)
    rms = {}
    for i, (scene, r) in enumerate(zip(shapes, scans)):
        t, p = r.result.trace
        dp = F.smooth(np.nan_to_num(F.delta_p(t, p, ref.t_rel, ref.p)), 201) / KPA
        moving = (t >= 60.0) & (t <= 60.0 + scene.length_mm / scene.speed_mm_s)
        x = (t[moving] - 60.0) * scene.speed_mm_s
        gap = np.array([cal.invert(v).estimate for v in dp[moving][::50]])
        xs = x[::50]
        surface_est = scene.base_mm - gap
        surface_true = scene.surface_mm(xs)
        rms[scene.shape] = float(np.sqrt(np.mean((surface_est - surface_true) ** 2)))
        ax[i, 0].plot(xs, surface_true, "k-", lw=1, label="true surface")
        ax[i, 0].plot(xs, surface_est, "r-", lw=1, label="reconstructed from dP")
        ax[i, 0].set_ylabel(f"{scene.shape} (mm)")
        ax[i, 0].legend(fontsize=7)
    ax[1, 0].set_xlabel("x along the scan (mm)")
    name = save(fig, out, "profile_scan.png")
    sec.numbers["rms_mm"] = {k: r4(v) for k, v in rms.items()}
    sec.row("profile reconstruction", "profiles reconstructed from dP via a calibration",
            ", ".join(f"{k} RMS {v:.2f} mm" for k, v in rms.items()), None,
            "amplitude 8 mm over 25 mm periods, 2 mm/s", "Fig. 2h-i")
    sec.markdown = "\n".join([
        f"Profile `{prof.name}`: {prof.description}. After 60 s of inflation the surface moves under the tip for "
        "100 mm at 2 mm/s. dP (against a free-air reference, smoothed over 0.2 s) is converted to a tip-surface "
        "distance with a quadratic dP_eq-h calibration on flat plates.", "", img(name, "profile scan"), "",
        "RMS error of the reconstructed surface: " + ", ".join(f"{k} {v:.2f} mm" for k, v in rms.items()) + "."])
    return sec


def suction(out: Path, seed: int) -> Section:
    prof = profile("suction-cup")
    sec = Section("suction", "Suction cup on silicone samples, and the pull test")
    mats = ["OO-50", "OO-30", "OO-10", "OOO-34"]

    async def body(ctrl):
        res = {}
        for p0 in (-62.0, -21.0):
            res[p0] = await sweep(ctrl, None, None, [SampleScene(material=m) for m in mats], cycles=5, drop_first=1,
                                  p0_kpa=p0)
        return res

    res = run_on(prof, body, seed)
    means = {p0: [np.mean([r.result.p_eq for r in runs if r.scene.material == m]) / KPA for m in mats]
             for p0, runs in res.items()}
    spans = {p0: means[p0][-1] - means[p0][0] for p0 in means}
    pull = profile("suction-cup-pull")
    pulls = []
    for k in range(3):
        async def one(ctrl):
            s = pull.sequence
            scene = PullScene(material="OO-30", rate_n_per_s=0.2, delay_s=s.charge_s + s.isolate_s + 20.0)
            await ctrl.scene.place(scene)
            r = await ctrl.run_cycle()
            return scene, r, await ctrl.scene.truth()

        pulls.append(run_on(pull, one, seed + 100 + k))
    fig, ax = figure(2, 1)
    for p0 in means:
        ax[0, 0].plot([82.7, 69.0, 55.0, 17.0], means[p0], "o-", label=f"tank {p0:g} kPa")
    ax[0, 0].set_xscale("log")
    ax[0, 0].set_xlabel("sample modulus (kPa): OO-50, OO-30, OO-10, OOO-34")
    ax[0, 0].set_ylabel("P_eq (kPa)")
    ax[0, 0].legend()
    detach_f, detach_dp, slopes = [], [], []
    for scene, r, truth in pulls:
        t, p = r.trace
        since_set = t + r.t_open - r.t_start
        f = scene.force_n(since_set)
        t_det = truth["detached_at_s"] - r.t_start
        before = since_set < t_det - 0.3
        p0 = np.mean(p[(f == 0) & (t > 15.5) & before])
        lr = stats.linregress(f[before & (f > 0.2)], (p[before & (f > 0.2)] - p0) / KPA)
        slopes.append(lr.slope)
        detach_f.append(float(scene.force_n(t_det)))
        detach_dp.append(lr.slope * detach_f[-1] + lr.intercept)
        ax[0, 1].plot(f[before], (p[before] - p0) / KPA, lw=0.6)
    ax[0, 1].set_xlabel("pull force (N)")
    ax[0, 1].set_ylabel("dP since isolation (kPa)")
    name = save(fig, out, "suction.png")
    # detach prediction: force at which the fitted line reaches the mean detach dP of the other pulls
    preds = []
    for i in range(len(pulls)):
        others = [d for j, d in enumerate(detach_dp) if j != i]
        preds.append(np.mean(others) / slopes[i])
    sec.numbers.update({"p_eq_kpa": {str(k): [r4(x) for x in v] for k, v in means.items()},
                        "span_kpa": {str(k): r4(v) for k, v in spans.items()},
                        "detach_force_n": [r4(x) for x in detach_f], "detach_dp_kpa": [r4(x) for x in detach_dp],
                        "predicted_detach_n": [r4(x) for x in preds]})
    sec.row("suction cup: softer sample, less negative P_eq", "four silicones distinguished",
            "monotonic" if np.all(np.diff(means[-62.0]) > 0) else "not monotonic", bool(np.all(np.diff(means[-62.0]) > 0)),
            "", "Fig. retrofit 2c-d")
    sec.row("P0 tunes the suction resolution", "-62 vs -21 kPa", f"span {spans[-62.0]:.2f} vs {spans[-21.0]:.2f} kPa",
            None, "eq. 2: resolution grows with p0", "Fig. retrofit 2d")
    sec.row("pull test: detachment", "dP about 1.2 kPa at a mean 4.53 N",
            f"dP {np.mean(detach_dp):+.2f} kPa at a mean {np.mean(detach_f):.2f} N",
            abs(np.mean(detach_f) - 4.53) < 0.5 and 0.8 < abs(np.mean(detach_dp)) < 1.6,
            "area and pull compliance set from these figures", "Fig. retrofit 2e")
    sec.row("detach prediction from force-pressure", "possible (linear)",
            f"predicted {np.mean(preds):.2f} N vs actual {np.mean(detach_f):.2f} N", None, "leave-one-out", "Fig. retrofit 2e")
    sec.markdown = "\n".join([
        f"Profile `{prof.name}` ({prof.description}), five cycles per sample, the first dropped, at two tank "
        "pressures; pull test with `suction-cup-pull` (cup isolated 15 s after opening, then pulled at 0.2 N/s).",
        "", img(name, "suction cup"), "",
        md_table(["tank P0", *mats, "span"], [[f"{p0:g} kPa", *means[p0], spans[p0]] for p0 in means]), "",
        f"Pull test (3 runs): detached at {', '.join(f'{x:.2f}' for x in detach_f)} N after dP "
        f"{', '.join(f'{x:+.2f}' for x in detach_dp)} kPa; the linear force-pressure fit predicts detachment at "
        f"{', '.join(f'{x:.2f}' for x in preds)} N (leave-one-out)."])
    return sec


RETROFIT = [
    ("filament-muscle", "stopper", "angle_deg", [0, 10, 20, 30], "deg", 1.0),
    ("mckibben-muscle", "stopper", "angle_deg", [0, 10, 20, 30], "deg", 6.0),
    ("tpu-bending", "cylinder", "diameter_mm", [40, 60, 80, 100], "mm", None),
    ("piab-vacuum-gripper", "cylinder", "diameter_mm", [40, 50, 60, 70, 80], "mm", None),
    ("srt-pneunet-gripper", "cylinder", "diameter_mm", [40, 60, 80, 100], "mm", None),
]
TABLE_S1 = {"piab-vacuum-gripper": (0.16, 0.08), "srt-pneunet-gripper": (0.13, 0.04)}


def retrofit(out: Path, seed: int) -> Section:
    sec = Section("retrofit", "Retrofitted actuators and commercial grippers")
    fig, ax = figure(3, 2, width=3.6, height=2.8)
    rows, s1 = [], []
    for i, (name, kind, target, values, unit, span_paper) in enumerate(RETROFIT):
        prof = profile(name)
        base = StopperScene(angle_deg=0) if kind == "stopper" else CylinderScene(diameter_mm=values[0])
        runs = run_on(prof, lambda c, b=base, t=target, v=values: sweep(c, b, t, v, cycles=6, drop_first=1), seed)
        means = [np.mean([r.result.p_eq for r in runs if r.target == v]) / KPA for v in values]
        sds = [np.std([r.result.p_eq for r in runs if r.target == v], ddof=1) / KPA for v in values]
        span = abs(means[-1] - means[0])
        a = ax[i // 3, i % 3]
        a.errorbar(values, means, yerr=sds, fmt="o-")
        a.set_title(name, fontsize=8)
        a.set_xlabel(f"{target}")
        a.set_ylabel("P_eq (kPa)")
        rows.append([name, f"{values[0]:g}-{values[-1]:g} {unit}", means[0], means[-1], span])
        sec.numbers[name] = {"p_eq_kpa": [r4(m) for m in means], "span_kpa": r4(span)}
        if span_paper is not None:
            sec.row(f"{name}: output span over 0-30 deg", f"about {span_paper:g} kPa", f"{span:.2f} kPa",
                    abs(span - span_paper) / span_paper < 0.3, "geometry chosen from this figure (docs/physics.md)",
                    "Fig. retrofit 1; Discussion")
        if name in TABLE_S1:
            lr = stats.linregress(values, means)
            law_v = []
            for v, m in zip(values, means):
                law = volume_law(prof.actuator, CylinderScene(diameter_mm=v), P_ATM)
                law_v.append(float(law.volume_at(m * KPA)))
            dv = stats.linregress(values, law_v).slope / ML
            mid = len(values) // 2
            computed = eq2_resolution(prof.sequence.p0_pa, prof.circuit.tank_m3, prof.actuator.v0, law_v[mid],
                                      dv * ML, P_ATM) / KPA
            dv_p, dp_p = TABLE_S1[name]
            s1.append([name, dv_p, abs(dv), dp_p, abs(computed), abs(lr.slope)])
            sec.numbers[name].update({"dv1_dD_ml_per_mm": r4(abs(dv)), "dp1_dD_eq2": r4(abs(computed)),
                                      "dp1_dD_measured": r4(abs(lr.slope))})
            sec.row(f"Table S1 {name}: |dv1/dD|", f"{dv_p} ml/mm", f"{abs(dv):.3f} ml/mm", abs(abs(dv) - dv_p) < 0.03,
                    "wrap ratio set from this figure", "Table S1")
            sec.row(f"Table S1 {name}: |dp1/dD| measured", f"{dp_p} kPa/mm", f"{abs(lr.slope):.4f} kPa/mm",
                    abs(abs(lr.slope) - dp_p) / dp_p < 0.25, "follows from eq. 2 with our v0 (assumed)", "Table S1")
    ax[1, 2].axis("off")
    name_fig = save(fig, out, "retrofit.png")
    spans = [r[4] for r in rows]
    sec.row("absolute pressure change across actuators", "1.3 to 5.9 kPa", f"{min(spans):.1f} to {max(spans):.1f} kPa",
            min(spans) > 0.6 and max(spans) < 9, "", "Table 1")
    sec.markdown = "\n".join([
        "Six cycles per target, the last five used, P_eq over each profile's window.", "",
        img(name_fig, "retrofit actuators"), "",
        md_table(["profile", "range", "P_eq first (kPa)", "P_eq last (kPa)", "span (kPa)"], rows), "",
        "Table S1, computed (eq. 2 at the middle of the range, with the model's volumes) against measured (slope of "
        "the simulated P_eq):", "",
        md_table(["gripper", "paper |dv1/dD| (ml/mm)", "ours |dv1/dD|", "paper |dp1/dD| (kPa/mm)",
                  "ours eq. 2", "ours measured"], s1)])
    return sec


def resolution(out: Path, seed: int) -> Section:
    sec = Section("resolution", "Resolution model and design")
    sweeps = {"l0_mm": np.linspace(20, 1500, 40), "area_mm2": np.linspace(100, 3000, 40),
              "stiffness_n_per_m": np.geomspace(50, 5000, 40), "p0_kpa": np.linspace(5, 90, 40),
              "tank_l": np.geomspace(0.02, 1.0, 40)}
    fig, ax = figure(3, 2, width=3.6, height=2.8)
    worst = 0.0
    for i, (param, values) in enumerate(sweeps.items()):
        rows = linear_sweep(param, values)
        num = np.array([r["numeric_kpa_per_mm"] for r in rows])
        ana = np.array([r["analytic_kpa_per_mm"] for r in rows])
        contact = np.array([r["contact"] for r in rows])
        if contact.any():
            worst = max(worst, float(np.max(np.abs(num[contact] / ana[contact] - 1))))
        a = ax[i // 3, i % 3]
        a.plot(values, -ana, "k--", lw=1, label="eq. 11")
        a.plot(values, -num, "r-", lw=1, label="numerical")
        a.set_xlabel(LINEAR_PARAMS[param] + f" ({param.split('_', 1)[1] if '_' in param else ''})")
        a.set_ylabel("|dp1/dL| (kPa/mm)")
        if param in ("stiffness_n_per_m", "tank_l"):
            a.set_xscale("log")
        a.legend(fontsize=7)
    ax[1, 2].axis("off")
    name = save(fig, out, "resolution_sweeps.png")
    sec.numbers["max_rel_diff_in_contact"] = r4(worst)
    sec.row("numerical vs analytic resolution where contact happens", "agree until the wall is out of reach",
            f"largest difference {100 * worst:.3f} %", worst < 0.02, "", "Fig. S modelV4 f-i")
    design_rows = []
    for pname in ("pneunet-bending", "pneunet-gripper", "piab-vacuum-gripper", "suction-cup", "tpu-bending"):
        prof = profile(pname)
        plan = prof.calibration
        from tasks.calibrate import scene_with

        targets = list(np.linspace(min(plan.values), max(plan.values), 5))
        vac = prof.sequence.p0_kpa < 0
        limit = prof.limits.min_kpa if vac else prof.limits.max_kpa
        best, grid = search(prof.actuator, lambda x, s=plan.scene, t=plan.target: scene_with(s, t, x), targets,
                            list(np.geomspace(prof.circuit.tank_l / 10, prof.circuit.tank_l * 10, 12)),
                            list(np.linspace(limit / 12, limit, 12)), P_ATM,
                            (prof.limits.min_kpa, prof.limits.max_kpa), tuple(prof.sensor.range_kpa))
        from simulator.resolution import evaluate

        cur = evaluate(prof.actuator, lambda x, s=plan.scene, t=plan.target: scene_with(s, t, x), targets,
                       prof.circuit.tank_l, prof.sequence.p0_kpa, P_ATM, (prof.limits.min_kpa, prof.limits.max_kpa),
                       tuple(prof.sensor.range_kpa))
        design_rows.append([pname, f"{prof.circuit.tank_l:.3g} L @ {prof.sequence.p0_kpa:g} kPa", cur.min_resolution,
                            "none" if best is None else f"{best.tank_l:.3g} L @ {best.p0_kpa:.3g} kPa",
                            float("nan") if best is None else best.min_resolution])
    sec.numbers["design"] = [[r[0], r4(r[2]), r[3], r4(r[4])] for r in design_rows]
    sec.markdown = "\n".join([
        "The linear extension actuator against a wall at L = 20 mm (eq. 6): resolution from the equilibrium of "
        "eq. 1 with the actuator's volume law (the state the dynamic model of eq. 3-9 settles at) against the "
        "analytic eq. 11, one parameter varied at a time around A = 500 mm^2, l0 = 100 mm, k = 300 N/m, "
        "p0 = 50 kPa, 0.1 L. The numerical resolution drops to zero once the actuator cannot reach the wall "
        "(long, stiff), which eq. 11 cannot show.", "", img(name, "resolution sweeps"), "",
        "`fluidsense design` on the shipped profiles (worst-case resolution over the calibration range; "
        "contact at every target, P0 within the limits, P_eq within the sensor's range):", "",
        md_table(["profile", "current", "worst |dP/dxi| now", "recommended", "worst |dP/dxi| then"], design_rows)])
    return sec


SECTIONS = [distance_tank, distance_pressure_flow, distance_flow_control, gripper, shape, stiffness, profile_scan,
            suction, retrofit, resolution]
