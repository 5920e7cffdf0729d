"""Speed against accuracy for one profile and scene: how early can each sensing method
decide, and how well (``fluidsense chart``; the paper's scenes: ``python -m lab bench
speed-accuracy``, which calls this module).

From virtual-time cycles of the profile on the simulated cell: a free-air reference, then
every method calibrated on fixed targets (``cal_cycles`` each, the first dropped) and
tested on ``trials`` held-out cycles whose targets are drawn uniformly from the range, at
each decision time t_d. One recorded cycle gives the features at every t_d (they only use
samples up to t_d: controller/sensing/decision.py), and each t_d has its own calibration.

At each t_d a method is *decided* on a cycle when it gives an estimate: the t_c and dP
methods need contact, the early estimator answers "not yet" until its 95 % half-width is
below ``early_half_width`` (the target's unit), and an inversion outside what the
calibration reaches is no estimate. The 95 % error is over the decided cycles; the decided
fraction is theirs over all. The fraction need not grow with t_d before the pressure has
settled: each t_d has its own calibration, and one taken early (the window before contact,
the early estimator just after it) may not invert at all.

Beside the methods, the physical floor from the plant's noise-free step responses at both
ends of the range: ``contact_s`` when the farthest target is touched (before it nothing
tells the far targets apart), ``settled_s`` when every response is within ``settled_kpa``
of its final value (after it a reading no longer depends on when it is taken).
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from itertools import combinations
from typing import Any

import numpy as np
from fluidsense.common.errors import ConfigError, FluidsenseError
from fluidsense.controller.config import Profile
from fluidsense.controller.ports import OpenCell
from fluidsense.controller.sensing.decision import METHODS

from .calibrate import scene_with

log = logging.getLogger(__name__)

# the coarse grid of the paper's scenes (a profile's own: coarse_times)
DECISION_TIMES = (0.1, 0.2, 0.3, 0.5, 1.0, 2.0, 5.0)
# ... and, per scene, a fine grid from the farthest contact (nothing decides before it) to
# twice the settled time, in steps of 5 % of the settled time: it resolves the ratio of the
# earliest decision to that floor to 0.05, which the coarse grid cannot (the paper's plate on
# the fast circuit settles at about 0.15 s; 0.1 s steps give it ratios of 0.7, 1.4, 2.0)
FINE_STEP_OF_FLOOR = 0.05
FINE_UP_TO_FLOORS = 2.0
DECIDED = 0.95  # a method "decides" at t_d when at least this fraction of cycles has an estimate
FIT = {"window": "linear", "early": "linear", "dp_max": "linear", "t_c_slope": "poly2", "t_c_threshold": "poly2"}
SETTLED_KPA = 0.07  # the paper's scenes: settled within one sample's noise sd of the final pressure
STEP_END_S = 8.0  # the paper's scenes: the step responses' length (their final value is read at it)
TAIL_S = 0.5  # a profile's actuation is cut this long after its last reading (nothing after it is used)

Progress = Callable[[str, int], None]  # (stage, steps just done)


@dataclass(frozen=True)
class ChartScene:
    """What is varied: ``base`` with ``target`` set to each calibration target and each
    held-out one (drawn uniformly from ``range``); ``unit`` is the target's."""

    base: Any
    target: str
    unit: str
    calibration: tuple[float, ...]
    range: tuple[float, float]

    def at(self, value: float) -> Any:
        return scene_with(self.base, self.target, value)


@dataclass(frozen=True)
class Plan:
    """How the chart is measured and scored. The defaults are the paper's scenes';
    ``for_profile`` gives a profile's own."""

    trials: int = 200
    cal_cycles: int = 6  # per calibration target, the first dropped
    seed: int = 1
    early_half_width: float = 2.0  # the early estimator decides once its 95 % half-width is this narrow
    settled_kpa: float = SETTLED_KPA
    step_end_s: float = STEP_END_S
    coarse: tuple[float, ...] = DECISION_TIMES
    last_s: float = 5.0  # the last decision time: the reference (the window mean there)
    sorting: tuple[float, ...] = ()  # spacings of the pairs whose order is scored (the paper's sorting)

    def __post_init__(self) -> None:
        if self.trials < 2 or self.cal_cycles < 2:
            raise ConfigError(f"trials ({self.trials}) and calibration cycles per target ({self.cal_cycles}, the "
                              "first dropped) must each be at least 2")


@dataclass
class Measured:
    """The features of every kept cycle at every decision time: ``cal`` and ``test`` are
    (target, {t_d: {method: value}}) per cycle, in the order they ran."""

    cal: list
    test: list
    times: tuple[float, ...]
    floor: dict[str, float]
    wall_s: float = 0.0


# ------------------------------------------------------------------ a profile's own chart
def coarse_times(last_s: float) -> tuple[float, ...]:
    """The 1-2-3-5 series from 0.1 s up to ``last_s``, and ``last_s`` itself."""
    series = [m * 10.0**e for e in range(-1, 4) for m in (1, 2, 3, 5)]
    return tuple(sorted({round(t, 3) for t in series if t < last_s - 1e-9} | {round(float(last_s), 3)}))


def for_profile(profile: Profile, scene: ChartScene, *, trials: int = 200, cal_cycles: int = 6, seed: int = 1,
                early_half_width: float | None = None) -> tuple[Profile, Plan]:
    """A profile's chart: its own cycle, read up to the end of its first window (the last
    decision time, whose window mean is the reference), its actuation cut TAIL_S after its
    last reading (nothing later is used); settled within its sensor's noise; the early
    estimator's gate 1/30 of the range unless given (2 mm over the paper gripper's 60 mm)."""
    seq = profile.sequence
    if seq.method != "tank" or profile.circuit.kind != "tank":
        raise ConfigError(f"profile {profile.name!r}: the chart runs the tank circuit's cycle (sequence.method tank); "
                          f"this profile's method is {seq.method!r} with a {profile.circuit.kind} circuit")
    last = float(seq.windows[0].end_s)
    used = max([w.end_s for w in seq.windows] + [seq.isolate_actuator_at_s or 0.0])
    actuate = min(seq.actuate_s, used + TAIL_S)
    prepared = profile.model_copy(update={"sequence": seq.model_copy(update={"actuate_s": actuate}),
                                          "calibration": None})
    lo, hi = scene.range
    noise = profile.sensor.noise_sd_kpa
    plan = Plan(trials=trials, cal_cycles=cal_cycles, seed=seed,
                early_half_width=(hi - lo) / 30.0 if early_half_width is None else early_half_width,
                settled_kpa=noise if noise > 0 else SETTLED_KPA, step_end_s=max(STEP_END_S, 2.0 * last),
                coarse=coarse_times(last), last_s=last)
    if not plan.early_half_width > 0:
        raise ConfigError(f"the early estimator's gate must be positive, got {plan.early_half_width:g}")
    return prepared, plan


# ------------------------------------------------------------------ the grid and the floor
def fine_step(floor: dict[str, float]) -> float:
    """The fine grid's step for one floor, rounded to the ms."""
    return max(1e-3, round(FINE_STEP_OF_FLOOR * floor["settled_s"], 3))


def decision_times(floor: dict[str, float], coarse: Sequence[float] = DECISION_TIMES,
                   last_s: float | None = None) -> tuple[float, ...]:
    """The grid of one scene: the coarse one and the fine one around its floor (``floor``:
    ``contact_s`` and ``settled_s``), up to ``last_s`` (default: the coarse grid's last), in
    seconds rounded to the ms."""
    last_s = coarse[-1] if last_s is None else last_s
    step = fine_step(floor)
    first = max(np.ceil(floor["contact_s"] / step - 1e-9) * step, step)  # (touching from the start: not at 0 s)
    last = min(FINE_UP_TO_FLOORS * floor["settled_s"], last_s)
    fine = [t for t in np.arange(first, last + step / 2, step) if t <= last + 1e-9]
    return tuple(sorted({round(float(t), 3) for t in (*coarse, *fine) if t <= last_s + 1e-9}))


def floor(profile: Profile, scene: ChartScene, settled_kpa: float = SETTLED_KPA,
          t_end_s: float = STEP_END_S) -> dict[str, float]:
    """The physical floor of one profile and scene, from the plant's noise-free step
    responses at both ends of the range."""
    from fluidsense.drivers.sim.floor import step_floor

    ends = scene.range
    resps = step_floor(profile.hardware, [scene.at(x) for x in ends], profile.sequence.p0_kpa, settled_kpa, t_end_s)
    missed = [x for x, (tc, _) in zip(ends, resps) if tc is None]
    if missed:
        raise ConfigError(f"profile {profile.name!r}: the actuator does not reach {scene.target} = "
                          + " or ".join(f"{x:g}" for x in missed) + f" {scene.unit} within {t_end_s:g} s at P0 "
                          f"{profile.sequence.p0_kpa:g} kPa (noise-free step response): narrow the range")
    return {"contact_s": max(tc for tc, _ in resps), "settled_s": max(s for _, s in resps)}


# ------------------------------------------------------------------ the cycles
def test_targets(scene: ChartScene, trials: int, seed: int) -> list[float]:
    lo, hi = scene.range
    return [round(float(x), 3) for x in np.random.default_rng(seed).uniform(lo, hi, trials)]


def steps(scene: ChartScene, plan: Plan) -> int:
    """What ``measure`` and ``score`` report to ``progress``, in all: every cycle run, every
    kept cycle's features, every method scored."""
    kept = len(scene.calibration) * (plan.cal_cycles - 1) + plan.trials
    return 1 + len(scene.calibration) * plan.cal_cycles + plan.trials + kept + len(METHODS)


async def _collect(prof: Profile, scene: ChartScene, targets: Sequence[float], cal_cycles: int, seed: int,
                   times: Sequence[float], progress: Progress, open_cell: OpenCell):
    from fluidsense.controller.sensing.decision import features_at

    from .experiments import reference, sim_cell, sweep

    def ran() -> None:
        progress("running cycles", 1)

    cfg, backend = sim_cell(prof, seed)
    async with open_cell(cfg, backend) as port:
        ref = await reference(port)
        ran()
        rt, rp = ref.trace
        cal = await sweep(port, scene.base, scene.target, scene.calibration, cycles=cal_cycles, drop_first=1,
                          on_cycle=ran)
        test = await sweep(port, scene.base, scene.target, targets, cycles=1, on_cycle=ran)
    thr = prof.sequence.contact_threshold_kpa
    sign = 1.0 if prof.sequence.p0_kpa >= 0 else -1.0

    def feats(runs):
        out = []
        for r in runs:
            out.append((r.target, features_at(*r.result.trace, rt, rp, times, contact_kpa=thr, sign=sign)))
            progress("reading features", 1)
        return out

    return feats(cal), feats(test)


def measure(profile: Profile, scene: ChartScene, plan: Plan, progress: Progress | None = None, *,
            open_cell: OpenCell) -> Measured:
    """The floor, the grid and every kept cycle's features (virtual time, one seeded cell:
    the same figures every run). ``open_cell`` starts a controller on that cell
    (service.open_cell)."""
    progress = progress or (lambda stage, n: None)
    t0 = time.perf_counter()
    fl = floor(profile, scene, plan.settled_kpa, plan.step_end_s)
    log.info("%s: farthest target touched at %.3f s, settled at %.3f s", profile.name, fl["contact_s"],
             fl["settled_s"])
    times = decision_times(fl, plan.coarse, plan.last_s)
    targets = test_targets(scene, plan.trials, plan.seed)
    cal, test = asyncio.run(_collect(profile, scene, targets, plan.cal_cycles, plan.seed, times, progress,
                                     open_cell))
    return Measured(cal, test, times, fl, time.perf_counter() - t0)


# ------------------------------------------------------------------ the scoring
def evaluate(cal, test, method: str, td: float, early_half_width: float) -> dict[str, Any]:
    """One method at one decision time: calibrated on ``cal``, tested on ``test``."""
    from fluidsense.controller.sensing.calibration import Calibration, CalibrationError

    xs = [x for x, f in cal if f[td][method] is not None]
    ys = [f[td][method] for x, f in cal if f[td][method] is not None]
    trials = len(test)
    meta = dict(profile="", method="", feature=method, feature_unit="", scene={}, target="", target_unit="mm",
                date="bench")
    none = {"err95": None, "bias": None, "decided_fraction": 0.0, "trials": trials, "estimates": []}
    if len(set(xs)) < 3:
        return none
    try:
        curve = Calibration.fit_points(xs, ys, FIT[method], **meta)
    except CalibrationError:
        return none
    slope = abs(curve.slope) or 1e-12
    errs, pairs = [], []
    for x, f in test:
        v = f[td][method]
        if v is None:
            continue
        if method == "early":
            sd = f[td].get("early_sd")
            if sd is None or 1.96 * sd / slope > early_half_width:
                continue  # "not yet": the interval is still too wide
        try:
            est = curve.invert(v).estimate
        except CalibrationError:
            continue
        errs.append(est - x)
        pairs.append((x, est))
    if not errs:
        return none
    e = np.array(errs)
    return {"err95": float(np.percentile(np.abs(e), 95)), "bias": float(e.mean()),
            "decided_fraction": len(errs) / trials, "trials": trials, "estimates": pairs}


def sorting(pairs: Sequence[tuple[float, float]], spacing: float) -> float | None:
    """Fraction of object pairs about ``spacing`` apart (within 1) that the estimates order right."""
    ok = n = 0
    for (x1, e1), (x2, e2) in combinations(pairs, 2):
        if abs(abs(x1 - x2) - spacing) <= 1.0:
            n += 1
            ok += (x1 - x2) * (e1 - e2) > 0
    return ok / n if n else None


def score(m: Measured, plan: Plan, trials: int | None = None, progress: Progress | None = None) -> list[dict]:
    """Every method at every decision time, over the first ``trials`` held-out cycles (all
    by default): rows of method, decision_time_s, err95, bias (the target's unit),
    decided_fraction, trials and, per ``plan.sorting`` spacing s, sorting[s]."""
    progress = progress or (lambda stage, n: None)
    test = m.test if trials is None else m.test[:trials]
    rows = []
    for method in METHODS:
        for td in m.times:
            ev = evaluate(m.cal, test, method, td, plan.early_half_width)
            pairs = ev.pop("estimates")
            rows.append({"method": method, "decision_time_s": td, **ev,
                         "sorting": {s: sorting(pairs, s) for s in plan.sorting}})
        progress("scoring", 1)
    return rows


def same_as(trials: int) -> float:
    """Relative tolerance for "no worse than": one standard error of the difference of two
    95th percentiles of |error| estimated from ``trials`` cycles each (normal errors: the
    percentile's own relative standard error is sqrt(0.05 * 0.95 / n) / (2 phi(1.96) 1.96))."""
    phi = np.exp(-1.96**2 / 2) / np.sqrt(2 * np.pi)
    return float(np.sqrt(2) * np.sqrt(0.05 * 0.95 / trials) / (2 * phi * 1.96))


def earliest(rows: Sequence[dict], trials: int, last_s: float, err: str = "err95") -> list[dict[str, Any]]:
    """Per method: the earliest decision time at which at least DECIDED of the cycles are
    decided with a 95 % error no worse than the window mean's at ``last_s`` (the reference),
    within the sampling tolerance ``same_as(trials)``. ``decision_time_s`` None: not by
    ``last_s``. ``rows``: one scene's; ``err``: the rows' error key."""
    tol = same_as(trials)
    ref = next(r for r in rows if r["method"] == "window" and r["decision_time_s"] == last_s)[err]
    out = []
    for method in METHODS:
        ok = [r for r in rows if r["method"] == method and r[err] is not None and r["decided_fraction"] >= DECIDED
              and ref is not None and r[err] <= ref * (1 + tol)]
        best = min(ok, key=lambda r: r["decision_time_s"], default=None)
        out.append({"method": method, "reference_err95": ref,
                    "decision_time_s": None if best is None else best["decision_time_s"],
                    "err95": None if best is None else best[err]})
    return out


def round_rows(rows: Sequence[dict]) -> list[dict]:
    """Floats to 4 significant digits (what the written figures keep)."""
    return [{k: (float(f"{v:.4g}") if isinstance(v, float) else v) for k, v in r.items()} for r in rows]


# ------------------------------------------------------------------ one chart
def chart(profile: Profile, scene: ChartScene, plan: Plan, progress: Progress | None = None, *,
          open_cell: OpenCell) -> dict[str, Any]:
    """The chart's figures for a prepared profile (``for_profile``) and a scene: what the
    JSON of ``fluidsense chart`` holds, but for the provenance and the file names.
    ``open_cell``: see ``measure``."""
    m = measure(profile, scene, plan, progress, open_cell=open_cell)
    t0 = time.perf_counter()
    rows = score(m, plan, progress=progress)
    for r in rows:
        if not r["sorting"]:
            del r["sorting"]
    first = earliest(rows, plan.trials, plan.last_s)
    ref = first[0]["reference_err95"]
    if ref is None:
        raise FluidsenseError(f"the window mean at {plan.last_s:g} s could not be calibrated: no reference to "
                              "score against (are the targets told apart at all?)")
    return {"profile": profile.name, "scene": scene.base.model_dump(mode="json"), "target": scene.target,
            "unit": scene.unit, "range": list(scene.range), "calibration_targets": list(scene.calibration),
            "cal_cycles": plan.cal_cycles, "trials": plan.trials, "seed": plan.seed,
            "early_half_width": plan.early_half_width, "decided_at": DECIDED, "same_as": same_as(plan.trials),
            "p0_kpa": profile.sequence.p0_kpa, "actuate_s": profile.sequence.actuate_s,
            "floor": {**m.floor, "settled_kpa": plan.settled_kpa},
            "reference": {"method": "window", "decision_time_s": plan.last_s, "err95": ref},
            "decision_times_s": list(m.times), "earliest": first, "rows": round_rows(rows),
            "wall_s": m.wall_s + time.perf_counter() - t0}


__all__ = ["DECIDED", "DECISION_TIMES", "ChartScene", "Measured", "Plan", "chart", "coarse_times", "decision_times",
           "earliest", "evaluate", "fine_step", "floor", "for_profile", "measure", "round_rows", "same_as",
           "score", "sorting", "steps"]
