"""Contact parameters from a few known targets (``fluidsense characterise --targets``).

The simulator's contact law (simulator/actuators.py) is the actuator's free P-V line whose
compliance drops to a fraction at the growth where the object is touched. Per actuator
kind, with the free line (v0, c) already fitted on the rig:

- gripper (cylinder of diameter D): touched after ``(open_mm - D) / closing_mm_per_ml`` ml
  of growth, then ``wrap_ratio`` of c;
- bending (plate at height h): touched after ``h / travel_mm_per_ml`` ml, then
  ``contact_ratio`` of c;
- muscle (stopper at angle a): touched after ``a / deg_per_ml`` ml, then ``blocked_ratio``.

Two readings per target show the law, each averaged over the target's cycles at the
profile's P0:

- the equilibrium's rise over free air, dP_eq (the free cycles run just before the
  targets): eq. 1 with the contact law, solved as the simulator solves it;
- the pressure at which the rise leaves the free rise, p_c: before contact the target's
  cycle and a free one pass every pressure on the same path (one state, one law), only
  shifted in time by the valve's timing; at contact the compliance drops and the target's
  cycle reaches each pressure sooner. Read on the crossing times of a grid of pressures
  (no time alignment needed): a hinge fitted where the difference leaves its baseline.
  On the law, p_c = growth at contact / c.

What the readings tell apart: the equilibria alone show two combinations (for a gripper
the offset and slope of dP_eq against D, which ``(1 - wrap) (open - D) / closing`` and
``wrap`` set): with the opening kept, closing and wrap are fitted, and absorb an error in
the opening (the equilibria stay reproduced, the contact pressures do not). The contact
pressures at two sizes fix the growth at contact against size (for a gripper its slope
1/closing and the opening); the equilibria then fix the ratio. So: a gripper with contact
read at two targets or more fits open_mm, closing_mm_per_ml and wrap_ratio; without,
closing_mm_per_ml and wrap_ratio (open_mm kept, said so). A bending actuator or a muscle
has two parameters, both fitted from two targets.

Refused, naming why: a target that reads as free air (not touched by P0), two targets
that read the same within their spread (too close together to tell), readings that do
not move with size the way the actuator kind's do, a residual beyond the spread
(lack-of-fit test, where there are more readings than parameters), a parameter outside
its physical range or not determined (its 95 % half-width over half its value).
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from fluidsense.common.errors import ConfigError, FluidsenseError, JobStopped
from fluidsense.common.hardware import PORT_VOLUME_M3
from fluidsense.common.scenes import TARGETS, CylinderScene, EmptyScene, PlateScene, StopperScene
from fluidsense.common.units import KPA, ML
from fluidsense.controller.config.profile import FittedNumber, Profile
from fluidsense.controller.ports import OpenCell, TaskPort
from scipy import optimize, stats

from .journal import CycleJournal
from .stopping import fault_dict, stopped_message

Place = Callable[[Any], Any]

MIN_TARGETS = 2
MIN_CYCLES = 2  # a spread per target needs two
GRID_POINTS = 400  # the pressures whose crossing times are kept per cycle: P0 / 400 apart (0.16 kPa at 63 kPa)
SMOOTH_S = 0.005  # moving average before the crossings are taken (5 samples at 1 kHz)
DEPART_K = 8.0  # the rise has left the free one where it is this many sd of the free cycles' spread ahead
DEPART_RUN = 5  # ... for this many grid pressures in a row
MIN_BASELINE = 6  # grid pressures needed before contact to read where the rise left the free one
SEPARATE_Z = 4.0  # two readings differ when their difference is beyond this many standard errors
LACK_OF_FIT_P = 0.001
MAX_REL_HALF_WIDTH = 0.5  # a parameter known no better than this is not told apart by the targets
CONTACT_MODEL_SD_KPA = 0.25  # the contact pressure's reading against the law's (departure())
FLOOR_S = 0.002  # a contact time this close to the controller's t_c_min is that floor, not the contact's
DRAWS = 40  # draws of the free line (v0, c) carried into the contact fit


@dataclass(frozen=True)
class KindSpec:
    """How an actuator kind touches its targets: the scene and field that sizes them, and
    the profile fields of its contact law."""

    scene: str
    offset: str | None  # the field of the size at which contact needs no growth (gripper: open_mm); None: 0
    rate: str  # size per ml of growth
    ratio: str  # the fraction of the free compliance left after contact
    closing: bool  # True: contact needs less growth the larger the target (a gripper's object)
    rate_unit: str

    @property
    def target(self) -> str:
        return TARGETS[self.scene][0]

    @property
    def unit(self) -> str:
        return TARGETS[self.scene][1]

    def scene_at(self, value: float):
        cls = {"cylinder": CylinderScene, "plate": PlateScene, "stopper": StopperScene}[self.scene]
        return cls(**{self.target: value})

    def growth_ml(self, value: float, offset: float, rate: float) -> float:
        """Growth at contact with a target of this size (ml; <= 0: touching from the start)."""
        return (offset - value) / rate if self.closing else (value - offset) / rate


KINDS: dict[str, KindSpec] = {
    "gripper": KindSpec("cylinder", "open_mm", "closing_mm_per_ml", "wrap_ratio", True, "mm/ml"),
    "bending": KindSpec("plate", None, "travel_mm_per_ml", "contact_ratio", False, "mm/ml"),
    "muscle": KindSpec("stopper", None, "deg_per_ml", "blocked_ratio", False, "deg/ml"),
}


def spec_of(profile: Profile) -> KindSpec:
    spec = KINDS.get(profile.actuator.kind)
    if spec is None:
        raise ConfigError(f"--targets: actuator kind {profile.actuator.kind!r} has no contact law fitted from "
                          f"targets (kinds: {', '.join(KINDS)})")
    return spec


def check_plan(profile: Profile, values: Sequence[float], cycles: int) -> list[float]:
    """The target sizes, sorted, or a ConfigError naming why; before any valve moves."""
    spec = spec_of(profile)
    if cycles < MIN_CYCLES:
        raise ConfigError(f"--target-cycles {cycles}: at least {MIN_CYCLES} per target are needed to state a "
                          "spread")
    out = sorted({round(float(v), 3) for v in values})
    if len(out) < MIN_TARGETS:
        raise ConfigError(f"--targets: {len(out)} distinct size(s); the contact law needs at least {MIN_TARGETS} "
                          f"(two parameters from two targets; a third tests the law)")
    for v in out:
        try:
            spec.scene_at(v)
        except ValueError as exc:
            raise ConfigError(f"--targets: {v:g} {spec.unit} is not a {spec.scene}'s {spec.target}: "
                              f"{str(exc).splitlines()[-1].strip()}") from exc
    return out


def grid_kpa(profile: Profile) -> list[float]:
    """The pressures (kPa, oriented away from atmosphere) at which each cycle's crossing
    time is kept: from P0/GRID_POINTS up to P0."""
    p0 = abs(profile.sequence.p0_kpa)
    return [round(p0 * (i + 1) / GRID_POINTS, 4) for i in range(GRID_POINTS)]


class ContactJournal(CycleJournal):
    """The finished cycles of the contact step (``OUT.contact.jsonl``): each line a free
    cycle (value None) or a target's, its equilibrium, its crossing times and the contact
    times the controller read against its free-air reference."""

    KIND = "fluidsense characterise contact cycles"
    WHAT = "a contact journal"

    @staticmethod
    def parse_entry(e: dict[str, Any]) -> dict[str, Any]:
        cross = [None if x is None else float(x) for x in e["cross_s"]]
        if len(cross) != GRID_POINTS:
            raise ValueError(f"cross_s has {len(cross)} times, not {GRID_POINTS}")
        return {"value": None if e["value"] is None else float(e["value"]), "k": int(e["k"]),
                "cycle_id": int(e["cycle_id"]), "p_eq_kpa": float(e["p_eq_kpa"]), "noise_kpa": float(e["noise_kpa"]),
                "t_c_threshold_s": None if e["t_c_threshold_s"] is None else float(e["t_c_threshold_s"]),
                "t_c_onset_s": None if e["t_c_onset_s"] is None else float(e["t_c_onset_s"]),
                "t_c_min_s": None if e["t_c_min_s"] is None else float(e["t_c_min_s"]), "cross_s": cross}

    @staticmethod
    def check_entry(entry: dict[str, Any], plan: dict[str, Any]) -> str | None:
        if entry["value"] is not None and entry["value"] not in plan["values"]:
            return f"a cycle at {entry['value']} is not in the plan"
        if not 0 <= entry["k"] < plan["cycles"]:
            return f"cycle {entry['k']} is not in the plan"
        return None


# ------------------------------------------------------------------ one cycle's trace
def crossings(t: np.ndarray, p: np.ndarray, sign: float, grid: Sequence[float]) -> list[float | None]:
    """When the trace (s since the commanded opening; Pa, offset removed) first crossed each
    grid pressure (kPa, oriented), on the trace averaged over SMOOTH_S; None where it never
    did."""
    q = sign * np.asarray(p, dtype=float) / KPA
    t = np.asarray(t, dtype=float)
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    w = max(1, int(round(SMOOTH_S / dt)) | 1)
    qs = np.convolve(q, np.ones(w) / w, mode="same") if q.size > w else q
    # the first crossing of each level: the running maximum is sorted, so one search does all
    peak = np.maximum.accumulate(qs)
    idx = np.searchsorted(peak, np.asarray(grid, dtype=float), side="left")
    out: list[float | None] = []
    for g, j in zip(grid, idx):
        if j <= 0 or j >= qs.size:
            out.append(None)
            continue
        a, b = qs[j - 1], qs[j]
        out.append(round(float(t[j - 1] + (g - a) * (t[j] - t[j - 1]) / (b - a)), 7) if b > a else float(t[j]))
    return out


def reading(res, value: float | None, k: int, grid: Sequence[float]) -> dict[str, Any]:
    t, p = res.trace
    sign = 1.0 if res.p0 >= 0 else -1.0
    return {"value": None if value is None else float(value), "k": k, "cycle_id": res.cycle_id,
            "p_eq_kpa": res.p_eq / KPA, "noise_kpa": res.p_sd / KPA, "t_c_threshold_s": res.t_c_threshold,
            "t_c_onset_s": res.t_c_onset, "t_c_min_s": res.t_c_min, "cross_s": crossings(t, p, sign, grid)}


# ------------------------------------------------------------------ the cycles
async def measure(port: TaskPort, values: Sequence[float], cycles: int, journal: ContactJournal,
                  place: Place, place_free: Place | None = None,
                  progress: Callable[[int], None] | None = None) -> list[dict]:
    """At the profile's P0: ``cycles`` free cycles (nothing there; the first is the
    controller's free-air reference, for its contact times), then ``cycles`` on each
    target, placed through ``place`` (the operator's prompts, or the simulated cell's
    scene). Each finished cycle goes into ``journal``; those already there are not run
    again. A run that cannot finish raises JobStopped with what it had done."""
    profile = port.profile
    spec = spec_of(profile)
    grid = grid_kpa(profile)
    p0 = profile.sequence.p0_kpa
    entries = journal.entries
    total = (len(values) + 1) * cycles
    place_free = place_free or place
    try:
        plan: list[float | None] = [None, *values]
        for value in plan:
            done = sum(1 for e in entries if e["value"] == value)
            if done >= cycles:
                continue
            if value is None:
                await place_free(EmptyScene())
            elif port.reference(p0 * KPA) is None:  # resumed after the free cycles
                await place_free(EmptyScene())
                res = await port.run_cycle(p0_kpa=p0, label="reference", store_reference=True)
                if not res.ok:
                    raise FluidsenseError(f"free-air reference cycle {res.cycle_id} ended: {res.aborted}")
            if value is not None:
                await place(spec.scene_at(value))
            for k in range(done, cycles):
                ref = value is None and port.reference(p0 * KPA) is None
                label = "free" if value is None else f"{spec.target}={value:g}"
                res = await port.run_cycle(p0_kpa=p0, label=f"characterise contact {label}", store_reference=ref)
                if not res.ok or res.trace is None or res.p_eq is None:
                    raise FluidsenseError(f"contact cycle {res.cycle_id} ({label}) ended: {res.aborted}")
                line = await asyncio.to_thread(reading, res, value, k, grid)
                await asyncio.to_thread(journal.add, line)
                if progress is not None:
                    progress(1)
    except (asyncio.CancelledError, KeyboardInterrupt):
        raise
    except FluidsenseError as exc:
        partial = {"completed": False, "cycles_done": len(entries), "cycles_total": total,
                   "journal": str(journal.path), "fault": fault_dict(port), "error": f"{type(exc).__name__}: {exc}"}
        raise JobStopped(stopped_message("contact characterisation", port, exc, f"{len(entries)} of {total} contact "
                                         "cycles") + f"; finished cycles are kept in {journal.path}: run again with "
                         "--resume", partial, partial["fault"]) from exc
    return entries


# ------------------------------------------------------------------ where the rise left the free one
@dataclass
class Departure:
    p_c_kpa: float | None
    why: str | None = None  # why no contact pressure was read


def departure(grid: np.ndarray, cross: np.ndarray, free_mean: np.ndarray, free_sd: np.ndarray,
              lo_kpa: float) -> Departure:
    """The pressure at which one cycle's rise left the free cycles' (their mean crossing
    times ``free_mean``, their spread ``free_sd``), from ``lo_kpa`` (where the rise is out of
    the noise). The difference of crossing times is constant before contact (the valve's
    timing) and falls after it, at first linearly (the compliance steps down: dt/dp steps
    down). The baseline is taken below the first run of DEPART_RUN pressures DEPART_K sd
    ahead of it; a hinge (constant, then a line in p - p_c) is fitted from lo_kpa to the
    end of that run, p_c where it fits best. Against the simulated plant (measured once
    while building it, not by the tests: 16 hidden quick PneuNet grippers, three sizes
    each, four cycles) the mean reading came -0.37 to +0.69 kPa
    from the law's contact pressure, sd 0.20 (smoothing, noise, the curvature after contact):
    the fit takes CONTACT_MODEL_SD_KPA as the reading's own error. A hinge at the start of
    the baseline is no reading (the rise was touched before it was read)."""
    d = cross - free_mean
    ok = np.isfinite(d) & np.isfinite(free_sd) & (grid >= lo_kpa)
    g, y, s = grid[ok], d[ok], free_sd[ok]
    if g.size < MIN_BASELINE + DEPART_RUN:
        return Departure(None, "too few pressures of the rise read")
    base = float(np.median(y[:MIN_BASELINE]))
    ahead = (base - y) > DEPART_K * np.maximum(s, 1e-5)
    run = np.convolve(ahead.astype(int), np.ones(DEPART_RUN, dtype=int), mode="valid") == DEPART_RUN
    first = np.flatnonzero(run)
    if not first.size:
        return Departure(None, "the rise never left the free one by more than its spread (touched near or after "
                         "the equilibrium, or not at all)")
    hi = int(first[0])
    if hi < MIN_BASELINE:
        return Departure(None, "the rise left the free one before it was out of the noise (touched at once)")
    end = hi + DEPART_RUN
    g, y = g[:end], y[:end]
    step = float(np.median(np.diff(g)))
    best = (math.inf, None)
    cands = np.arange(g[MIN_BASELINE // 2], g[end - 1], step / 10)
    for c in cands:
        x = np.maximum(g - c, 0.0)
        a = np.column_stack([np.ones_like(x), x])
        coef, *_ = np.linalg.lstsq(a, y, rcond=None)
        r = y - a @ coef
        sse = float(r @ r)
        if sse < best[0]:
            best = (sse, float(c))
    if best[1] is None or best[1] < g[MIN_BASELINE - 1]:
        return Departure(None, "the rise left the free one before it was out of the noise (touched at once)")
    return Departure(best[1])


@dataclass
class TargetReading:
    value: float | None  # None: free air
    n: int
    p_eq_kpa: float  # mean
    p_eq_sd_kpa: float
    dp_eq_kpa: float | None = None  # over free air, oriented
    p_c_kpa: float | None = None  # mean over the cycles where it was read
    p_c_sd_kpa: float | None = None
    p_c_n: int = 0
    p_c_why: str | None = None
    t_c_threshold_s: float | None = None
    t_c_threshold_sd_s: float | None = None
    t_c_threshold_n: int = 0
    t_c_floored: int = 0  # cycles whose contact time is the controller's floor (t_c_min), not the contact's
    t_c_onset_s: float | None = None
    cycle_ids: list[int] = field(default_factory=list)
    rise_s_per_kpa: float | None = None  # the free rise's dt/dp at this target's contact pressure


def readings(entries: Sequence[dict[str, Any]], profile: Profile) -> tuple[TargetReading, list[TargetReading]]:
    """The free cycles' and each target's readings (means over their cycles)."""
    sign = 1.0 if profile.sequence.p0_kpa >= 0 else -1.0
    grid = np.array(grid_kpa(profile))
    groups: dict[float | None, list[dict]] = {}
    for e in entries:
        groups.setdefault(e["value"], []).append(e)
    free = groups.pop(None, [])
    if len(free) < MIN_CYCLES:
        raise ContactRefused([f"too few free cycles: {len(free)} (at least {MIN_CYCLES})"])

    def cross(es: list[dict]) -> np.ndarray:
        return np.array([[np.nan if x is None else x for x in e["cross_s"]] for e in es], dtype=float)

    fc = cross(free)
    free_mean = fc.mean(axis=0)
    # a target's difference holds one target cycle's scatter and the free mean's
    free_sd = fc.std(axis=0, ddof=1) * math.sqrt(1 + 1 / len(free))
    noise = float(np.sqrt(np.mean([e["noise_kpa"] ** 2 for e in free])))
    p_free = np.array([sign * e["p_eq_kpa"] for e in free])
    lo = max(5 * noise, 0.02 * float(p_free.mean()))

    def mean_of(xs):
        xs = [x for x in xs if x is not None]
        return float(np.mean(xs)) if xs else None

    def group(value, es) -> TargetReading:
        pe = np.array([sign * e["p_eq_kpa"] for e in es])
        tcs = [e["t_c_threshold_s"] for e in es if e["t_c_threshold_s"] is not None]
        r = TargetReading(value, len(es), float(pe.mean()), float(pe.std(ddof=1)) if pe.size > 1 else 0.0,
                          t_c_threshold_s=mean_of(tcs), t_c_onset_s=mean_of([e["t_c_onset_s"] for e in es]),
                          t_c_threshold_sd_s=float(np.std(tcs, ddof=1)) if len(tcs) > 1 else None,
                          t_c_threshold_n=len(tcs), cycle_ids=[e["cycle_id"] for e in es])
        r.t_c_floored = sum(1 for e in es if e["t_c_threshold_s"] is not None and e["t_c_min_s"] is not None
                            and e["t_c_threshold_s"] <= e["t_c_min_s"] + FLOOR_S)
        return r

    free_r = group(None, free)
    out = []
    for value in sorted(groups):
        es = groups[value]
        r = group(value, es)
        r.dp_eq_kpa = r.p_eq_kpa - free_r.p_eq_kpa
        deps = [departure(grid, row, free_mean, free_sd, lo) for row in cross(es)]
        pcs = [d.p_c_kpa for d in deps if d.p_c_kpa is not None]
        if len(pcs) >= MIN_CYCLES and len(pcs) * 2 > len(deps):
            r.p_c_kpa, r.p_c_sd_kpa, r.p_c_n = float(np.mean(pcs)), float(np.std(pcs, ddof=1)), len(pcs)
            ok = np.isfinite(free_mean)
            slope = np.gradient(free_mean[ok], grid[ok])
            r.rise_s_per_kpa = float(np.interp(r.p_c_kpa, grid[ok], slope))
        else:
            whys = sorted({d.why for d in deps if d.why})
            r.p_c_why = (f"read in {len(pcs)} of {len(deps)} cycles" + (f" ({'; '.join(whys)})" if whys else ""))
        out.append(r)
    return free_r, out


# ------------------------------------------------------------------ the model and the fit
class ContactRefused(FluidsenseError):
    def __init__(self, reasons: list[str], result: ContactFit | None = None):
        self.reasons, self.result = reasons, result
        super().__init__("contact fit refused: " + "; ".join(reasons))


@dataclass
class ContactFit:
    fitted: list[FittedNumber]
    kept: dict[str, str]
    notes: list[str]
    free: TargetReading
    targets: list[TargetReading]
    model: dict[float, dict[str, float | None]]  # per target: the fitted law's dP_eq and p_c
    chi2: float | None
    dof: int

    def to_dict(self) -> dict[str, Any]:
        def row(r: TargetReading) -> dict[str, Any]:
            return {k: getattr(r, k) for k in ("value", "n", "p_eq_kpa", "p_eq_sd_kpa", "dp_eq_kpa", "p_c_kpa",
                                               "p_c_sd_kpa", "p_c_n", "p_c_why", "t_c_threshold_s", "t_c_onset_s")}
        return {"fitted": [f.model_dump() for f in self.fitted], "kept": self.kept, "notes": self.notes,
                "free": row(self.free), "targets": [{**row(r), "model": self.model.get(r.value)} for r in self.targets],
                "chi2": self.chi2, "dof": self.dof}


def law_equilibrium(p0: float, v_tank: float, v_side0: float, c: float, p_contact: float | None, ratio: float,
                    p_atm: float) -> float:
    """Gauge pressure (Pa) at which a tank of ``v_tank`` at gauge ``p0`` and an actuator side
    starting at atmosphere settle (eq. 1), the side on the contact law of
    simulator/actuators.py: ``v_side0 + c p`` up to ``p_contact`` (signed as p0; None: never
    touched; 0: touching from the start), then ``ratio`` of c. On a segment ``v = a + b p``
    eq. 1 is ``b p^2 + (Vt + a + b Pa) p + Pa (Vt + a) - M = 0``, solved in closed form (the
    root that goes to the linear one as b goes to zero); the free segment's root stands if it
    stops short of contact. tests/system/test_characterise_contact.py checks it against the
    simulator's own root search on its law."""
    m = (p0 + p_atm) * v_tank + p_atm * v_side0

    def root(a: float, b: float) -> float:
        big = v_tank + a + b * p_atm
        small = p_atm * (v_tank + a) - m
        return -2.0 * small / (big + math.sqrt(max(big * big - 4.0 * b * small, 0.0)))

    free = root(v_side0, c)
    if p_contact is None or abs(free) <= abs(p_contact):
        return free
    return root(v_side0 + (1.0 - ratio) * c * p_contact, ratio * c)


class LawModel:
    """The readings the simulator's contact law gives, for the profile's circuit and P0 and
    the free line (v_side = v0 + the stated hose and ports, c)."""

    def __init__(self, profile: Profile, v0_ml: float, c_ml_per_kpa: float):
        self.profile, self.spec = profile, spec_of(profile)
        circ = profile.circuit
        self.p_atm, self.v_tank, self.p0 = circ.p_atm, circ.tank_m3, profile.sequence.p0_pa
        hose = circ.hose.volume_m3 if circ.hose is not None else 0.0
        port = PORT_VOLUME_M3 if (circ.valve is not None and circ.resistor_pa_s_per_m3 > 0) else 0.0
        self.fixed = hose + port
        self.sign = 1.0 if self.p0 >= 0 else -1.0
        self.v0, self.c = v0_ml, c_ml_per_kpa
        self.p_free = self._eq(None, 1.0)

    def _param(self, params: dict[str, float], name: str | None) -> float:
        if name is None:
            return 0.0
        return float(params[name]) if name in params else float(getattr(self.profile.actuator, name))

    def growth_ml(self, value: float, params: dict[str, float]) -> float:
        return self.spec.growth_ml(value, self._param(params, self.spec.offset), self._param(params, self.spec.rate))

    def _eq(self, p_contact_kpa: float | None, ratio: float) -> float:
        p_c = None if p_contact_kpa is None else self.sign * p_contact_kpa * KPA
        p = law_equilibrium(self.p0, self.v_tank, self.v0 * ML + self.fixed, self.c * ML / KPA, p_c, ratio,
                            self.p_atm)
        return self.sign * p / KPA

    def dp_eq(self, value: float, params: dict[str, float]) -> float:
        growth = self.growth_ml(value, params)
        return self._eq(max(growth, 0.0) / self.c, self._param(params, self.spec.ratio)) - self.p_free

    def p_c(self, value: float, params: dict[str, float]) -> float | None:
        growth = self.growth_ml(value, params)
        return growth / self.c if growth > 0 else None


def _t95(dof: int) -> float:
    return float(stats.t.ppf(0.975, max(dof, 1)))


def fit(entries: Sequence[dict[str, Any]], profile: Profile, v0_ml: float, c_ml_per_kpa: float,
        pv_cov: np.ndarray | None = None) -> ContactFit:
    """The contact law's parameters from the contact cycles, with the free line (v0, c)
    fitted before (``pv_cov``: its covariance, carried by draws), or ContactRefused."""
    spec = spec_of(profile)
    free, targets = readings(entries, profile)
    unit = spec.unit
    refused: list[str] = []
    if len(targets) < MIN_TARGETS:
        raise ContactRefused([f"too few targets: {len(targets)} (at least {MIN_TARGETS})"])
    if min(r.n for r in targets) < MIN_CYCLES:
        raise ContactRefused([f"too few cycles at a target: {min(r.n for r in targets)} (at least {MIN_CYCLES})"])
    # the equilibrium's spread: pooled over the free cycles and every target's
    groups = [free, *targets]
    dof_p = sum(r.n - 1 for r in groups)
    s_p = math.sqrt(sum((r.n - 1) * r.p_eq_sd_kpa**2 for r in groups) / dof_p)
    if s_p <= 0:
        raise ContactRefused(["the cycles read exactly the same equilibrium: no spread to state an uncertainty from"])

    def se_dp(r: TargetReading) -> float:
        return s_p * math.sqrt(1 / r.n + 1 / free.n)

    # touched, and moving with size the kind's way (a gripper's larger object: touched sooner, higher P_eq)
    for r in targets:
        if r.dp_eq_kpa < SEPARATE_Z * se_dp(r):
            refused.append(f"the {r.value:g} {unit} target reads as free air (its P_eq {r.dp_eq_kpa:+.3g} kPa from "
                           f"free air's, +- {se_dp(r):.2g}): it is not touched by P0 "
                           + ("(smaller than the fingers' closing at P0)" if spec.closing else
                              "(beyond the actuator's reach at P0)"))
    by_size = sorted(targets, key=lambda r: r.value)
    for a, b in zip(by_size, by_size[1:]):
        step = (b.dp_eq_kpa - a.dp_eq_kpa) * (1 if spec.closing else -1)
        se = s_p * math.sqrt(1 / a.n + 1 / b.n)
        if abs(step) < SEPARATE_Z * se:
            refused.append(f"the {a.value:g} and {b.value:g} {unit} targets read the same within their spread "
                           f"(P_eq {a.p_eq_kpa:.4g} and {b.p_eq_kpa:.4g} kPa, +- {se:.2g}): too close together to "
                           "tell apart, or not touched")
        elif step < 0:
            refused.append(f"the readings do not move with size as a {profile.actuator.kind}'s do: the "
                           f"{b.value:g} {unit} target reads {'below' if spec.closing else 'above'} the "
                           f"{a.value:g} {unit} one (P_eq {b.p_eq_kpa:.4g} against {a.p_eq_kpa:.4g} kPa)")
    if refused:
        raise ContactRefused(refused)

    with_pc = [r for r in targets if r.p_c_kpa is not None]
    names = [spec.rate, spec.ratio]
    if spec.offset and len({r.value for r in with_pc}) >= 2:
        names = [spec.offset, *names]
    act = profile.actuator
    x0 = np.array([float(getattr(act, n)) for n in names])

    def model_and_data(v0: float, c: float):
        m = LawModel(profile, v0, c)
        ys = [r.dp_eq_kpa for r in targets] + [r.p_c_kpa for r in with_pc]
        # covariance: the free mean is common to every dP_eq
        n_t, n_c = len(targets), len(with_pc)
        cov = np.zeros((n_t + n_c, n_t + n_c))
        cov[:n_t, :n_t] = s_p**2 / free.n
        for i, r in enumerate(targets):
            cov[i, i] += s_p**2 / r.n
        for j, r in enumerate(with_pc):
            cov[n_t + j, n_t + j] = r.p_c_sd_kpa**2 / r.p_c_n + CONTACT_MODEL_SD_KPA**2
        return m, np.array(ys), np.linalg.cholesky(cov)

    def solve(v0: float, c: float, x_start: np.ndarray):
        m, ys, chol = model_and_data(v0, c)

        def predict(x: np.ndarray) -> np.ndarray:
            params = dict(zip(names, map(float, x)))
            pcs = [m.p_c(r.value, params) for r in with_pc]
            # a target the law does not touch on the rise: its contact pressure as at zero growth
            return np.array([m.dp_eq(r.value, params) for r in targets] + [0.0 if p is None else p for p in pcs])

        def resid(x: np.ndarray) -> np.ndarray:
            return np.linalg.solve(chol, predict(x) - ys)

        lo = [1e-4 if n == spec.ratio else 1e-6 for n in names]
        hi = [1.0 if n == spec.ratio else np.inf for n in names]
        sol = optimize.least_squares(resid, np.clip(x_start, np.array(lo) + 1e-9, np.array(hi) - 1e-9),
                                     bounds=(lo, hi), x_scale=np.abs(x_start) + 1e-3)
        return sol, predict

    sol, _ = solve(v0_ml, c_ml_per_kpa, x0)
    jac = sol.jac
    m_read = len(sol.fun)
    dof = m_read - len(names)
    try:
        cov = np.linalg.inv(jac.T @ jac)
    except np.linalg.LinAlgError:
        raise ContactRefused([f"the targets cannot tell {', '.join(names)} apart (a singular fit): targets farther "
                              "apart"]) from None
    chi2 = float(sol.fun @ sol.fun) if dof > 0 else None
    notes: list[str] = []
    if dof > 0:
        p_lof = float(stats.chi2.sf(chi2, dof))
        notes.append(f"contact fit: chi-square {chi2:.3g} on {dof} degree(s) of freedom (p = {p_lof:.2g})")
        if p_lof < LACK_OF_FIT_P:
            refused.append(f"the contact law does not fit the readings: they scatter {math.sqrt(chi2 / dof):.2g} times "
                           f"their spread about it (p = {p_lof:.2g}; an object that is soft or off-centre, a law that "
                           "is not piecewise linear)")
        cov = cov * max(1.0, chi2 / dof)
    else:
        notes.append(f"contact fit: {m_read} readings for {len(names)} parameters: the law passes through them "
                     "exactly; a further target would test it")
    # the free line's uncertainty, carried by draws (a fixed seed: the same readings give the same intervals)
    spread = np.zeros(len(names))
    if pv_cov is not None:
        draws = np.random.default_rng(0).multivariate_normal([v0_ml, c_ml_per_kpa], pv_cov, size=DRAWS)
        xs = []
        for v_d, c_d in draws:
            if v_d > 0 and c_d > 0:
                s_d, _ = solve(float(v_d), float(c_d), sol.x)
                xs.append(s_d.x)
        if len(xs) > 1:
            spread = np.std(np.array(xs), axis=0, ddof=1)
    dof_t = min([dof_p, *[r.p_c_n - 1 for r in with_pc]])
    t95 = _t95(dof_t)
    fitted: list[FittedNumber] = []
    units = {spec.offset: unit, spec.rate: spec.rate_unit, spec.ratio: ""}
    readings_words = (f"dP_eq over free air at {len(targets)} targets ({', '.join(f'{r.value:g}' for r in targets)} "
                      f"{unit}, {targets[0].n} cycles each, {free.n} free)"
                      + (f" and the contact pressure at {len(with_pc)}" if with_pc else ""))
    for i, name in enumerate(names):
        v = float(sol.x[i])
        h = math.sqrt((t95 * math.sqrt(cov[i, i])) ** 2 + (1.96 * spread[i]) ** 2)
        fitted.append(FittedNumber(field=f"actuator.{name}", value=v, lo95=v - h, hi95=v + h, unit=units[name],
                                   how=f"the simulator's contact law fitted to {readings_words} at P0 "
                                   f"{profile.sequence.p0_kpa:g} kPa (eq. 1 solved with the law; weighted by the "
                                   "readings' spread), with the fitted v0 and c and their uncertainty"
                                   + (": the contact pressures fix it times c, so its interval carries c's"
                                      if name == spec.rate else "")))
        if h > MAX_REL_HALF_WIDTH * abs(v):
            refused.append(f"{name} is not told apart by these targets ({v:.4g} +- {h:.2g}): targets farther apart "
                           "(or more cycles)")
        if name == spec.ratio and (v - h > 1.0 or v >= 0.999):
            refused.append(f"{name} {v:.3g}: contact does not lower the compliance (the targets are not rigid, or "
                           "not touched)")
        if name == spec.offset and v - h <= max(r.value for r in targets):
            refused.append(f"{name} {v:.4g} (+- {h:.2g}) is not beyond the largest target: the largest target "
                           "would be touched from the start")
    kept: dict[str, str] = {}
    if spec.offset and spec.offset not in names:
        kept[f"actuator.{spec.offset}"] = (
            "no contact pressure was read at two targets: the equilibria alone show (1 - {spec.ratio}) ({spec.offset} - D) / {spec.rate} and "
            f"{spec.ratio}, so {spec.offset} is kept as the starting profile's and {spec.rate} and {spec.ratio} "
            f"absorb an error in it (the equilibria at these targets are reproduced, the contact pressures need "
            "not be)")
    for extra in ("push_ratio", "force_area_mm2"):
        if hasattr(act, extra):
            kept[f"actuator.{extra}"] = "rigid, centred targets do not show it: kept"
    for r in targets:
        if r.p_c_kpa is None:
            notes.append(f"no contact pressure at the {r.value:g} {unit} target: {r.p_c_why}")
    params = dict(zip(names, map(float, sol.x)))
    m = LawModel(profile, v0_ml, c_ml_per_kpa)
    model = {r.value: {"dp_eq_kpa": m.dp_eq(r.value, params), "p_c_kpa": m.p_c(r.value, params)} for r in targets}
    result = ContactFit(fitted, kept, notes, free, targets, model, chi2, dof)
    if refused:
        raise ContactRefused(refused, result)
    return result


# ------------------------------------------------------------------ the check: the written profile's simulated cell
class _Memory:
    """A journal that keeps its cycles in memory (the simulated check's)."""

    path = "(memory)"

    def __init__(self) -> None:
        self.entries: list[dict[str, Any]] = []

    def add(self, entry: dict[str, Any]) -> None:
        self.entries.append(entry)


async def simulate(profile: Profile, values: Sequence[float], cycles: int, seed: int,
                   open_cell: OpenCell) -> list[dict[str, Any]]:
    """The contact step's cycles on the simulated cell of ``profile`` (virtual time), each
    target laid out by the cell itself. ``open_cell`` starts a controller on that cell
    (service.open_cell: tasks do not import the service)."""
    from .experiments import sim_cell

    cfg, backend = sim_cell(profile, seed)
    async with open_cell(cfg, backend) as port:
        return await measure(port, values, cycles, _Memory(), place=port.place)  # type: ignore[arg-type]


@dataclass
class Check:
    free: TargetReading
    targets: list[TargetReading]
    lines: list[str]  # per reading, in words
    disagree: list[str]  # the readings the simulated cell does not reproduce

    @property
    def ok(self) -> bool:
        return not self.disagree


def compare(rig: ContactFit, sim_entries: Sequence[dict[str, Any]], profile: Profile, timing_fitted: bool) -> Check:
    """The simulated cell's readings against the rig's: dP_eq and the contact pressure
    judged (they differ when beyond SEPARATE_Z standard errors of their difference, the
    contact pressure's own error CONTACT_MODEL_SD_KPA included), and the controller's
    contact time where the rise's timing was fitted (``timing_fitted``: a laminar circuit's
    path, or an ISO valve's C; its error includes the contact pressure's, over the free
    rise's slope there); the
    absolute P_eq reported (the free equilibrium is the free fit's, and a regulator that
    lands anew only when its setpoint changes shifts every P_eq of a session alike)."""
    free, targets = readings(sim_entries, profile)
    spec = spec_of(profile)

    def pooled(groups: list[TargetReading]) -> float:
        dof = sum(r.n - 1 for r in groups)
        return math.sqrt(sum((r.n - 1) * r.p_eq_sd_kpa**2 for r in groups) / dof) if dof else 0.0

    s_rig, s_sim = pooled([rig.free, *rig.targets]), pooled([free, *targets])
    lines = [f"free air: P_eq rig {rig.free.p_eq_kpa:.4g} kPa (sd {rig.free.p_eq_sd_kpa:.2g}), simulated "
             f"{free.p_eq_kpa:.4g} ({free.p_eq_kpa - rig.free.p_eq_kpa:+.2g})"]
    disagree: list[str] = []
    sims = {r.value: r for r in targets}
    for r in rig.targets:
        s = sims[r.value]
        name = f"{r.value:g} {spec.unit}"
        d = s.dp_eq_kpa - r.dp_eq_kpa
        se = math.sqrt(s_rig**2 * (1 / r.n + 1 / rig.free.n) + s_sim**2 * (1 / s.n + 1 / free.n))
        words = (f"{name}: dP_eq rig {r.dp_eq_kpa:.4g} kPa, simulated {s.dp_eq_kpa:.4g} ({d:+.2g}, {d / se:+.1f} se; "
                 f"P_eq {r.p_eq_kpa:.4g} and {s.p_eq_kpa:.4g}, the rig's spread {r.p_eq_sd_kpa:.2g})")
        if abs(d) > SEPARATE_Z * se:
            disagree.append(f"dP_eq at {name}")
        if r.p_c_kpa is not None and s.p_c_kpa is not None:
            dc = s.p_c_kpa - r.p_c_kpa
            sec = math.sqrt(r.p_c_sd_kpa**2 / r.p_c_n + s.p_c_sd_kpa**2 / s.p_c_n)
            words += (f"; contact at {r.p_c_kpa:.4g} and {s.p_c_kpa:.4g} kPa ({dc:+.2g}, {dc / max(sec, 1e-9):+.1f} "
                      "se)")
            if abs(dc) > SEPARATE_Z * math.hypot(sec, CONTACT_MODEL_SD_KPA):
                disagree.append(f"the contact pressure at {name}")
        elif (r.p_c_kpa is None) != (s.p_c_kpa is None):
            words += f"; contact pressure read on {'the rig' if s.p_c_kpa is None else 'the simulated cell'} only"
        if r.t_c_floored or s.t_c_floored:
            who = " and ".join(x for x, y in (("the rig's", r), ("the simulated cell's", s)) if y.t_c_floored)
            words += (f"; contact time {_ms(r.t_c_threshold_s)} and {_ms(s.t_c_threshold_s)} ms, {who} at the "
                      "controller's floor (no contact time before the reference's rise has passed its alignment "
                      "levels, t_c_min): not judged")
        elif r.t_c_threshold_s is not None and s.t_c_threshold_s is not None:
            dt = s.t_c_threshold_s - r.t_c_threshold_s
            words += (f"; contact time {1e3 * r.t_c_threshold_s:.1f} and {1e3 * s.t_c_threshold_s:.1f} ms "
                      f"({1e3 * dt:+.1f}")
            if r.t_c_threshold_sd_s is not None and s.t_c_threshold_sd_s is not None:
                own = CONTACT_MODEL_SD_KPA * (r.rise_s_per_kpa or 0.0)
                se_t = math.sqrt(r.t_c_threshold_sd_s**2 / r.t_c_threshold_n
                                 + s.t_c_threshold_sd_s**2 / s.t_c_threshold_n + own**2)
                words += f", {dt / max(se_t, 1e-9):+.1f} se"
                if timing_fitted and abs(dt) > SEPARATE_Z * se_t:
                    disagree.append(f"the contact time at {name}")
            words += ")" if timing_fitted else "; the rise's timing is the starting profile's: not judged)"
        lines.append(words)
    return Check(free, targets, lines, disagree)


def _ms(t: float | None) -> str:
    return "none" if t is None else f"{1e3 * t:.1f}"


def provenance(fit_: ContactFit, profile: Profile, cycles: int, check: Check | None) -> dict[str, Any]:
    """The ``provenance.contact`` block (controller/config/profile.py ContactProvenance)."""
    from fluidsense.controller.config.profile import ContactProvenance, ContactReading

    spec = spec_of(profile)

    def row(r: TargetReading, law: dict | None = None) -> ContactReading:
        return ContactReading(size=r.value, cycles=r.n, cycle_ids=r.cycle_ids, p_eq_kpa=r.p_eq_kpa,
                              p_eq_sd_kpa=r.p_eq_sd_kpa, dp_eq_kpa=r.dp_eq_kpa, p_contact_kpa=r.p_c_kpa,
                              p_contact_sd_kpa=r.p_c_sd_kpa, p_contact_note=r.p_c_why,
                              t_c_threshold_s=r.t_c_threshold_s,
                              law_dp_eq_kpa=None if law is None else law["dp_eq_kpa"],
                              law_p_contact_kpa=None if law is None else law["p_c_kpa"])

    block = ContactProvenance(
        scene=spec.scene, target=spec.target, unit=spec.unit, p0_kpa=profile.sequence.p0_kpa,
        cycles_per_target=cycles, free=row(fit_.free), readings=[row(r, fit_.model[r.value]) for r in fit_.targets],
        chi2=fit_.chi2, dof=fit_.dof,
        simulated=[] if check is None else [row(check.free), *(row(r) for r in check.targets)],
        check=[] if check is None else check.lines)
    return block.model_dump(mode="json")
