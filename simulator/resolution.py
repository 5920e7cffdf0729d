"""Sensing resolution: the numerical model against the paper's analytic one, and a
design search for tank volume and P0 (paper, "Characterizing the sensing resolution" and
Methods "Modeling the fluidic sensing approach", Fig. S modelV4).

Numerical resolution here is the derivative of the equilibrium of eq. 1 solved with the
actuator's volume law (``equilibrium``), which the dynamic plant settles at (checked in
the tests); it drops to zero when the actuator cannot reach what it should touch. The
analytic eq. 11 assumes contact and never drops.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from fluidsense.common.hardware import LinearActuator
from fluidsense.common.scenes import EmptyScene, WallScene
from fluidsense.common.units import KPA, LITRE, MM
from fluidsense.simulator.actuators import volume_law
from fluidsense.simulator.equilibrium import eq11_resolution, equilibrium
from fluidsense.simulator.gas import VolumeLaw

SceneAt = Callable[[float], Any]  # target value -> scene


@dataclass(frozen=True)
class Point:
    target: float
    p_eq: float  # Pa gauge
    dp_dxi: float  # Pa per target unit
    contact: bool  # touching at the target and on both sides of the difference
    edge: bool = False  # touching at the target but not on both sides: the derivative straddles the edge


def resolution_at(actuator, scene_at: SceneAt, target: float, step: float, p0: float, v_tank: float,
                  p_atm: float, bounds: tuple[float, float] = (-np.inf, np.inf),
                  law_at: Callable[[float | None], VolumeLaw] | None = None) -> Point:
    """Equilibrium and its derivative (central difference, one-sided at ``bounds``) at one
    target value. ``law_at``: the actuator's volume law at a target value (None: free air),
    when a caller evaluating many tanks and P0s keeps them (``search``: a law depends on
    neither)."""
    law_at = law_at or _laws(actuator, scene_at, p_atm)

    def peq(x: float) -> float:
        return equilibrium(p0, v_tank, law_at(x), p_atm)

    p_free = equilibrium(p0, v_tank, law_at(None), p_atm)

    def touching(p: float) -> bool:
        return abs(p - p_free) > 1e-6 * max(abs(p_free), 1.0)

    a, b = max(target - step, bounds[0]), min(target + step, bounds[1])
    p, pa, pb = peq(target), peq(a), peq(b)
    d = (pb - pa) / (b - a)
    everywhere = touching(p) and touching(pa) and touching(pb)
    return Point(target, p, d, everywhere, edge=touching(p) and not everywhere)


def _laws(actuator, scene_at: SceneAt, p_atm: float) -> Callable[[float | None], VolumeLaw]:
    """The volume law at a target value (None: free air), each built once."""
    kept: dict[float | None, VolumeLaw] = {}

    def law_at(x: float | None) -> VolumeLaw:
        if x not in kept:
            kept[x] = volume_law(actuator, EmptyScene() if x is None else scene_at(x), p_atm)
        return kept[x]

    return law_at


# --------------------------------------------------------- linear actuator (Fig. S modelV4)
LINEAR_PARAMS = {"l0_mm": "initial length l0", "area_mm2": "cross section A",
                 "stiffness_n_per_m": "stiffness k", "p0_kpa": "tank pressure p0", "tank_l": "tank volume"}


def linear_sweep(param: str, values: Sequence[float], base: LinearActuator | None = None, wall_mm: float = 20.0,
                 p0_kpa: float = 50.0, tank_l: float = 0.1, p_atm: float = 101_325.0) -> list[dict[str, Any]]:
    """Resolution dp1/dL of the linear actuator against a wall at ``wall_mm`` while one
    parameter varies: numerical (equilibrium of eq. 1 with eq. 6) and analytic (eq. 11)."""
    if param not in LINEAR_PARAMS:
        raise KeyError(f"unknown parameter {param!r}; sweepable: {', '.join(LINEAR_PARAMS)}")
    base = base or LinearActuator()
    rows = []
    for value in values:
        act, p0, vt = base, p0_kpa * KPA, tank_l * LITRE
        if param in ("l0_mm", "area_mm2", "stiffness_n_per_m"):
            act = base.model_copy(update={param: float(value)})
        elif param == "p0_kpa":
            p0 = float(value) * KPA
        else:
            vt = float(value) * LITRE
        pt = resolution_at(act, lambda x: WallScene(distance_mm=x), wall_mm, 0.25, p0, vt, p_atm)
        analytic = eq11_resolution(p0, vt, act.area, act.l0, wall_mm * MM, p_atm) * MM  # Pa/mm
        rows.append({"param": param, "value": float(value), "numeric_kpa_per_mm": pt.dp_dxi / KPA,
                     "analytic_kpa_per_mm": analytic / KPA, "contact": pt.contact, "edge": pt.edge,
                     "p_eq_kpa": pt.p_eq / KPA})
    return rows


# ------------------------------------------------------------------- design search
@dataclass
class Design:
    tank_l: float
    p0_kpa: float
    min_resolution: float  # |dp/dxi| at the worst point of the range, kPa per target unit
    mean_resolution: float
    p_eq_range_kpa: tuple[float, float]
    feasible: bool
    reason: str = ""

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["p_eq_range_kpa"] = list(self.p_eq_range_kpa)
        return d


def evaluate(actuator, scene_at: SceneAt, targets: Sequence[float], tank_l: float, p0_kpa: float, p_atm: float,
             p_limits_kpa: tuple[float, float], sensor_kpa: tuple[float, float],
             law_at: Callable[[float | None], VolumeLaw] | None = None) -> Design:
    """Resolution over the target range for one (tank, P0); infeasible when the actuator
    misses the target somewhere, or the pressures leave the limits or the sensor's range."""
    step = 0.25 * float(np.min(np.diff(sorted(targets)))) if len(targets) > 1 else 0.25
    bounds = (min(targets), max(targets))
    pts = [resolution_at(actuator, scene_at, x, step, p0_kpa * KPA, tank_l * LITRE, p_atm, bounds, law_at)
           for x in targets]
    res = np.array([abs(p.dp_dxi) for p in pts]) / KPA
    peq = np.array([p.p_eq for p in pts]) / KPA
    lo, hi = sorted((float(peq.min()), float(peq.max())))
    d = Design(tank_l, p0_kpa, float(res.min()), float(res.mean()), (lo, hi), True)
    if not all(p.contact or p.edge for p in pts):
        missed = [p.target for p in pts if not (p.contact or p.edge)]
        d.feasible, d.reason = False, f"no contact at target {missed[0]:g}"
    elif not p_limits_kpa[0] <= p0_kpa <= p_limits_kpa[1]:
        d.feasible, d.reason = False, "P0 outside the profile's limits"
    elif not (sensor_kpa[0] < lo and hi < sensor_kpa[1]):
        d.feasible, d.reason = False, "P_eq outside the sensor's range"
    return d


def search(actuator, scene_at: SceneAt, targets: Sequence[float], tanks_l: Sequence[float],
           p0s_kpa: Sequence[float], p_atm: float, p_limits_kpa: tuple[float, float],
           sensor_kpa: tuple[float, float]) -> tuple[Design | None, list[Design]]:
    """Every (tank, P0) on the grid; the best is the feasible one with the largest worst-case
    resolution (ties: the smaller P0, then the smaller tank)."""
    # the volume laws depend on the target, not on the tank or P0: built once per target
    # value, not once per grid point (about half of a search's time)
    law_at = _laws(actuator, scene_at, p_atm)
    grid = [evaluate(actuator, scene_at, targets, vt, p0, p_atm, p_limits_kpa, sensor_kpa, law_at)
            for vt in tanks_l for p0 in p0s_kpa]
    feasible = [d for d in grid if d.feasible]
    best = max(feasible, key=lambda d: (round(d.min_resolution, 6), -abs(d.p0_kpa), -d.tank_l), default=None)
    return best, grid
