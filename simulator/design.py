"""Design for a requirement: the tank volume and P0 that reach an accuracy by a decision
time, given the sensor's noise (paper, "Characterizing the sensing resolution": the tank
volume and P0 set the slope of P_eq against the target, eq. 1-2; the flow resistance
sets the response time, Fig. S response time).

Per candidate (tank, P0):
- resolution |dP_eq/dx| at the worst target of the range (``resolution.evaluate``);
- noise of one reading: the sensor's noise averaged over the window, the offset's noise
  averaged over the offset window, and the cycle-to-cycle spread of P0 (the regulator's
  repeatability) carried to P_eq by dP_eq/dP0 (eq. 1 with the actuator's compliance);
- predicted 95 % half-width: 1.96 x that noise / resolution;
- settle time: tank, resistor and actuator as one first-order circuit (time constant R x
  the two capacities in series, linearised at P_eq); the reading may start once the
  transient is below a quarter of one resolution step. The window (up to 10 s) ends at
  the decision time.
The recommendation is the lowest P0 (then the smallest tank) that meets both: P0 is
not pushed to its limit when less does the job; it stays inside the profile's limits
by the profile's margin.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

from fluidsense.common.units import KPA, LITRE
from fluidsense.simulator.actuators import volume_law
from fluidsense.simulator.equilibrium import equilibrium
from fluidsense.simulator.resolution import SceneAt, evaluate

Z95 = 1.96
MAX_WINDOW_S = 10.0  # the paper's longest window (the plate: the last 10 s of 60)


@dataclass
class Candidate:
    tank_l: float
    p0_kpa: float
    resolution_kpa: float  # worst |dP_eq/dx| over the range, kPa per target unit
    half_width: float  # predicted 95 % half-width of one reading, target unit
    settle_s: float  # from opening until the transient is below a quarter step
    window_s: float
    feasible: bool
    reason: str = ""
    meets: bool = False

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _settle_s(actuator, scene, tank_l: float, p0_kpa: float, p_atm: float, r_total: float, step_kpa: float,
              delay_s: float) -> float:
    law = volume_law(actuator, scene, p_atm)
    v_tank = tank_l * LITRE
    p_eq = equilibrium(p0_kpa * KPA, v_tank, law, p_atm)
    p_abs = p_atm + p_eq
    c_tank = v_tank / p_abs
    c_act = float(law.volume_at(p_eq)) / p_abs + float(law.compliance_at(p_eq))
    tau = r_total * c_tank * c_act / (c_tank + c_act)
    gap = max(abs(p_eq), 1e-9)
    return delay_s + tau * math.log(max(gap / max(step_kpa * KPA / 4, 1e-9), 1.0))


def _p0_gain(actuator, scene, tank_l: float, p0_kpa: float, p_atm: float) -> float:
    """dP_eq/dP0: how much of the regulator's error reaches the reading (eq. 1 with the
    actuator's compliance)."""
    law, v_tank, h = volume_law(actuator, scene, p_atm), tank_l * LITRE, 0.5 * KPA
    return abs(equilibrium(p0_kpa * KPA + h, v_tank, law, p_atm) - equilibrium(p0_kpa * KPA - h, v_tank, law, p_atm)) / (2 * h)


def assess(prof, scene_at: SceneAt, targets: Sequence[float], tank_l: float, p0_kpa: float, resolution: float,
           decide_by_s: float, rate_hz: float) -> Candidate:
    c, seq = prof.circuit, prof.sequence
    limits = (prof.limits.min_kpa, prof.limits.max_kpa)
    d = evaluate(prof.actuator, scene_at, targets, tank_l, p0_kpa, c.p_atm, limits, tuple(prof.sensor.range_kpa))
    margin = prof.p0_margin_kpa
    feasible, reason = d.feasible, d.reason
    if feasible and not limits[0] + margin <= p0_kpa <= limits[1] - margin:
        feasible, reason = False, f"P0 within the {margin:.2f} kPa margin of the limits"
    res = max(d.min_resolution, 1e-12)
    r_total = c.valve_resistance_pa_s_per_m3 + c.resistor_pa_s_per_m3
    worst = min(targets, key=lambda x: abs(x - targets[0]))  # the slow end is checked below too
    settle = max(_settle_s(prof.actuator, scene_at(x), tank_l, p0_kpa, c.p_atm, r_total, resolution * res,
                           getattr(c, "valve_delay_s", 0.0)) for x in (worst, targets[-1]))
    window = min(MAX_WINDOW_S, max(decide_by_s - settle, 0.0))
    sigma = prof.sensor.noise_sd_kpa
    cycle_sd = _p0_gain(prof.actuator, scene_at(targets[len(targets) // 2]), tank_l, p0_kpa, c.p_atm) * getattr(
        c, "regulator_repeatability_kpa", 0.0)
    n_win, n_off = max(window * rate_hz, 1.0), max(seq.offset_s * rate_hz, 1.0)
    reading_sd = math.sqrt(sigma**2 / n_win + sigma**2 / n_off + cycle_sd**2)
    half = Z95 * reading_sd / res
    meets = feasible and window > 0 and half <= resolution
    return Candidate(tank_l, p0_kpa, d.min_resolution, half, settle, window, feasible, reason, meets)


def recommend(prof, scene_at: SceneAt, targets: Sequence[float], tanks_l: Sequence[float],
              p0s_kpa: Sequence[float], resolution: float, decide_by_s: float,
              rate_hz: float = 1000.0) -> tuple[Candidate | None, list[Candidate], str]:
    """(the design, every candidate, why none if none)."""
    grid = [assess(prof, scene_at, targets, vt, p0, resolution, decide_by_s, rate_hz)
            for vt in tanks_l for p0 in p0s_kpa]
    good = [g for g in grid if g.meets]
    if good:
        return min(good, key=lambda g: (abs(g.p0_kpa), g.tank_l)), grid, ""
    feasible = [g for g in grid if g.feasible]
    if not feasible:
        reasons = sorted({g.reason for g in grid})
        return None, grid, "no tank and P0 on the grid is feasible: " + "; ".join(reasons)
    sharpest = min(feasible, key=lambda g: g.half_width)
    fastest = min(feasible, key=lambda g: g.settle_s)
    accurate = [g for g in feasible if g.half_width <= resolution]
    why = (f"the best reachable is +-{sharpest.half_width:.2g} per reading (tank {sharpest.tank_l:.3g} L at "
           f"{sharpest.p0_kpa:.3g} kPa, settled after {sharpest.settle_s:.2g} s)")
    if accurate:
        quickest = min(accurate, key=lambda g: g.settle_s)
        why = (f"the accuracy needs the transient to settle first: the quickest design that reaches it "
               f"(tank {quickest.tank_l:.3g} L at {quickest.p0_kpa:.3g} kPa) settles after "
               f"{quickest.settle_s:.2g} s, later than the decision time; a smaller flow resistance would help")
    elif fastest.settle_s < decide_by_s:
        why = f"the sensor's noise limits it: {why}; average more cycles or use a quieter sensor"
    else:
        why = (f"no design settles before the decision time (the quickest after {fastest.settle_s:.2g} s) and "
               f"{why}")
    return None, grid, why
