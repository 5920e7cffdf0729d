"""``python -m lab bench budget``: each distance method's held-out 95 % accuracy predicted
from its parts' figures (simulator/parts.py, the profile's ``budget`` block and the
existing repeatability and noise fields), and what each part contributes.

The plant here is the model's static equilibrium (eq. 1 with the actuator's volume law;
the dynamic cell settles at it, tests/unit/test_physics.py), which costs a root search per
cycle instead of an integration: thousands of calibrations and held-out sessions in
seconds. The protocol is the bench's (``python -m lab bench accuracy``): one calibration
session per trial set with the paper's protocol (h = 0..40 mm in 5 mm steps, 7 kept
cycles each, its own session draws), then fresh sessions, one held-out height each,
inverted with the calibration's own inverse-prediction interval
(controller/sensing/calibration.py). Time of first contact needs the dynamic cell: it is
not predicted here.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math

import numpy as np

NAME = "budget"
HELP = "each method's 95 % accuracy predicted from its parts' figures, and each part's share"
DESCRIPTION = __doc__

METHODS = {"tank": "pneunet-bending", "pressure_flow": "pneunet-bending-pressure-flow",
           "flow_control": "pneunet-bending-flow-control"}
PAPER_HALF_MM = {"tank": 1.7, "pressure_flow": 4.7, "flow_control": 3.4}  # Fig. S sensing accuracy a-c
HEIGHTS = [0, 5, 10, 15, 20, 25, 30, 35, 40]
NOTHING_MM = 200.0  # a plate this far is out of the actuator's reach: the empty reading
SOURCES = ("regulator repeatability (per cycle)", "regulator setpoint (per session)",
           "flow controller accuracy of rate (per session)", "flow controller repeatability (per cycle)",
           "flow sensor repeatability of reading (per cycle)", "placement (per target)",
           "sensor noise and resolution over the window (per sample)")


class Plant:
    """One method's static plant and its draws."""

    def __init__(self, method: str, on: frozenset[str] = frozenset(SOURCES), override: dict | None = None):
        from fluidsense.cli.options import profile_path
        from fluidsense.controller.config import load_profile

        self.method = method
        self.prof = load_profile(profile_path(METHODS[method]))
        if override:  # a figure varied over its stated range (simulator/parts.py)
            budget = self.prof.budget.model_copy(update=override)
            self.prof = self.prof.model_copy(update={"budget": type(budget).model_validate(budget.model_dump())})
        self.on = on
        c, b, seq = self.prof.circuit, self.prof.budget, self.prof.sequence
        self.rep_kpa = getattr(c, "regulator_repeatability_kpa", 0.0) if seq.p0_kpa else 0.0
        self.set_kpa = b.regulator_setpoint_kpa if seq.p0_kpa else 0.0
        self.mfc_rate = b.flow_controller_of_rate
        self.mfc_rep = getattr(c, "flow_repeatability", 0.0)
        self.fs_rep = b.flow_sensor_of_reading
        self.place_mm = b.placement_mm
        win = seq.windows[0]
        n = max(int((win.end_s - win.start_s) * 1000.0), 1)  # 1000 Hz, paper's Methods
        s = self.prof.sensor
        # the window's mean: white noise averages down; the quantum as a rectangular error
        self.window_sd_kpa = math.hypot(s.noise_sd_kpa, s.quantum_kpa / math.sqrt(12)) / math.sqrt(n)
        fs = self.prof.flow_sensor
        if seq.flow_window is not None:  # integrated flow: noise sd * dt * sqrt(n) in standard ml
            nf = int((seq.flow_window.end_s - seq.flow_window.start_s) * 1000.0)
            self.flow_int_sd_ml = math.hypot(fs.noise_sd_slpm, fs.quantum_slpm / math.sqrt(12)) * 1000 / 60 \
                * 1e-3 * math.sqrt(nf)
        else:
            self.flow_int_sd_ml = 0.0

    def _u(self, rng, half, name):
        return float(rng.uniform(-half, half)) if half > 0 and name in self.on else 0.0

    def _n(self, rng, sd, name):
        return float(rng.normal(0.0, sd)) if sd > 0 and name in self.on else 0.0

    def session(self, rng) -> dict[str, float]:
        return {"reg_kpa": self._u(rng, self.set_kpa, SOURCES[1]), "mfc": self._u(rng, self.mfc_rate, SOURCES[2])}

    def placed(self, rng, h: float) -> float:
        return max(h + self._u(rng, self.place_mm, SOURCES[5]), 0.0)

    def cycle(self, rng, sess: dict[str, float], h_true: float) -> float:
        """One cycle's feature (kPa or standard ml) at the plate's true height."""
        from fluidsense.common.scenes import PlateScene
        from fluidsense.common.units import KPA, ML, P_ATM, SLPM
        from fluidsense.simulator.actuators import volume_law
        from fluidsense.simulator.equilibrium import equilibrium
        from scipy import optimize

        law = volume_law(self.prof.actuator, PlateScene(height_mm=h_true), P_ATM)
        seq = self.prof.sequence
        reg = (sess["reg_kpa"] + self._n(rng, self.rep_kpa, SOURCES[0])) * KPA
        noise = self._n(rng, self.window_sd_kpa, SOURCES[6])
        if self.method == "tank":
            return equilibrium(seq.p0_kpa * KPA + reg, self.prof.circuit.tank_m3, law, P_ATM) / KPA + noise
        v0 = float(law.volume_at(0.0))
        if self.method == "pressure_flow":
            p = seq.p0_kpa * KPA + reg
            v_std = ((p + P_ATM) * float(law.volume_at(p)) - P_ATM * v0) / P_ATM / ML
            gain = 1.0 + self._u(rng, self.fs_rep, SOURCES[4])
            return v_std * gain + self._n(rng, self.flow_int_sd_ml, SOURCES[6])
        fp = seq.flow_profile  # ramp then hold: the delivered standard volume
        m = fp.flow_slpm * SLPM * (fp.ramp_s / 2 + fp.hold_s)
        m *= (1.0 + sess["mfc"]) * (1.0 + self._n(rng, self.mfc_rep, SOURCES[3]))
        total = P_ATM * (v0 + m)
        pg = optimize.brentq(lambda x: (x + P_ATM) * float(law.volume_at(x)) - total, 0.0, 200 * KPA, xtol=1e-6)
        return pg / KPA + noise


def predict(method: str, n_cal: int = 20, n_test: int = 50, seed: int = 1,
            on: frozenset[str] = frozenset(SOURCES), override: dict | None = None) -> dict[str, float]:
    """95 % |error| (mm), mean error and the coverage of the 95 % intervals over
    ``n_cal`` calibrations x ``n_test`` fresh held-out sessions."""
    from fluidsense.controller.sensing.calibration import Calibration

    plant = Plant(method, on, override)
    rng = np.random.default_rng([seed, 26])
    # the feature's spread over session draws alone (per-cycle parts off), at mid range:
    # what the calibration's session term (Profile.session_rel_sd, first order) stands for
    quiet = Plant(method, on & {SOURCES[1], SOURCES[2]}, override)
    session = [quiet.cycle(rng, quiet.session(rng), 20.0) for _ in range(200)]
    session_rel_sd = plant.prof.session_rel_sd if on & {SOURCES[1], SOURCES[2]} else 0.0
    # "no object": the empty actuator's readings (7 per calibration, as calibrate takes
    # them; one per held-out session) and a plate at the far end of the range, drawn from a
    # stream of their own so that every other figure here stays as it was without them
    free_rng = np.random.default_rng([seed, 27])
    err, cover, cover_own, empty_object, empty_object_own, end_nothing = [], [], [], [], [], []
    for _ in range(n_cal):
        sess = plant.session(rng)
        x, y = [], []
        for h in HEIGHTS:
            h_true = plant.placed(rng, h)
            for _k in range(7):
                x.append(h)
                y.append(plant.cycle(rng, sess, h_true))
        free = [plant.cycle(free_rng, sess, NOTHING_MM) for _ in range(7)]
        cal = Calibration.fit_points(x, y, "linear", date="budget", profile=plant.prof.name, method=method,
                                     feature="y", feature_unit="", scene={}, target="height_mm", target_unit="mm",
                                     session_rel_sd=session_rel_sd, free_y=free)
        own = dataclasses.replace(cal, session_rel_sd=0.0)  # the interval from its own session alone
        for _t in range(n_test):
            h = float(rng.uniform(0.5, 39.5))
            test_session = plant.session(rng)
            y_test = plant.cycle(rng, test_session, plant.placed(rng, h))
            y_empty = plant.cycle(free_rng, test_session, NOTHING_MM)
            empty_object.append(cal.free_reading(y_empty, 1) is None)
            empty_object_own.append(own.free_reading(y_empty, 1) is None)
            end_nothing.append(cal.free_reading(plant.cycle(free_rng, test_session, 39.5), 1) is not None)
            inv = cal.invert(y_test)
            err.append(inv.estimate - h)
            cover.append(inv.interval95[0] <= h <= inv.interval95[1])
            lo, hi = own.invert(y_test).interval95
            cover_own.append(lo <= h <= hi)
    e = np.array(err)
    return {"abs_error_95_mm": float(np.percentile(np.abs(e), 95)), "mean_error_mm": float(e.mean()),
            "coverage95": float(np.mean(cover)), "coverage95_own_session_only": float(np.mean(cover_own)),
            "session_sd": float(np.std(session)), "session_rel_sd_numeric": float(np.std(session) / np.mean(session)),
            "session_rel_sd": session_rel_sd, "trials": len(e),
            "empty_read_as_object": float(np.mean(empty_object)),
            "empty_read_as_object_own_session_only": float(np.mean(empty_object_own)),
            "plate_at_39_5_read_as_nothing": float(np.mean(end_nothing))}


def table(n_cal: int, n_test: int, seed: int, override: dict | None = None,
          methods: list[str] | None = None, shares: bool = True) -> list[dict]:
    rows = []
    for method in methods or list(METHODS):
        full = predict(method, n_cal, n_test, seed, override=override)
        parts = {}
        for src in SOURCES if shares else ():
            alone = predict(method, max(n_cal // 2, 2), max(n_test // 2, 5), seed, frozenset({src}), override)
            parts[src] = alone["abs_error_95_mm"]
        paper = PAPER_HALF_MM[method]
        rows.append({"method": method, "profile": METHODS[method], **full, "paper_half_mm": paper,
                     "ratio_to_paper": full["abs_error_95_mm"] / paper,
                     "within_25pct": abs(full["abs_error_95_mm"] - paper) <= 0.25 * paper, "alone_mm": parts})
    return rows


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("--calibrations", type=int, default=20, help="calibration sessions (default 20)")
    p.add_argument("--held-out", type=int, default=50, help="fresh held-out sessions per calibration (default 50)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--method", choices=list(METHODS), action="append", help="one method (repeatable; default all)")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="vary a budget figure over its stated range, e.g. --set placement_mm=1.0")
    p.add_argument("--no-shares", action="store_true", help="skip each part's share (one run per part)")
    p.add_argument("--json", action="store_true")


def run(args: argparse.Namespace) -> int:
    override = {k: float(v) for k, v in (item.split("=", 1) for item in args.set)}
    rows = table(args.calibrations, args.held_out, args.seed, override or None, args.method, not args.no_shares)
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    for r in rows:
        print(f"{r['method']} ({r['profile']}): 95 % |error| {r['abs_error_95_mm']:.2f} mm over {r['trials']} "
              f"held-out sessions (paper +-{r['paper_half_mm']} mm, x{r['ratio_to_paper']:.2f}, "
              f"{'within' if r['within_25pct'] else 'outside'} 25 %); mean {r['mean_error_mm']:+.2f} mm; "
              f"95 % intervals cover {100 * r['coverage95']:.1f} % ({100 * r['coverage95_own_session_only']:.1f} % "
              f"without the session term; its sd {100 * r['session_rel_sd']:.2f} % of the feature, "
              f"{100 * r['session_rel_sd_numeric']:.2f} % on the plant); an empty actuator read as an object in "
              f"{100 * r['empty_read_as_object']:.2f} % of fresh sessions "
              f"({100 * r['empty_read_as_object_own_session_only']:.2f} % without the session term), "
              f"a plate at 39.5 mm as nothing in "
              f"{100 * r['plate_at_39_5_read_as_nothing']:.2f} %")
        for src, v in r["alone_mm"].items():
            if v > 0:
                print(f"    {src}: alone {v:.2f} mm")
    return 0
