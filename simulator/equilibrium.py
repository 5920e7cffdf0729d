"""Static equilibrium and resolution (paper, "Characterizing the sensing resolution",
eq. 1-2, and Methods "Modeling", eq. 10-11).

``equilibrium`` solves eq. 1 with an actuator's volume law instead of assuming the final
volume: it is what the dynamic plant settles at (tests check that), and it costs a root
search instead of an integration, which is what the design tool sweeps need.
"""

from __future__ import annotations

from fluidsense.simulator.gas import VolumeLaw
from scipy import optimize


def equilibrium(p0_gauge: float, v_tank: float, law: VolumeLaw, p_atm: float) -> float:
    """Gauge pressure at which a tank charged to ``p0_gauge`` and an actuator starting at
    atmosphere settle: p0*v_tank + p_atm*v0 = p1*(v_tank + v1(p1)) (eq. 1, absolute)."""
    v0 = float(law.volume_at(0.0))
    total = (p0_gauge + p_atm) * v_tank + p_atm * v0

    def residual(pg: float) -> float:
        return (pg + p_atm) * (v_tank + float(law.volume_at(pg))) - total

    lo, hi = sorted((0.0, p0_gauge))
    if lo == hi:
        return lo
    return float(optimize.brentq(residual, lo, hi, xtol=1e-9, rtol=1e-12))


def eq2_resolution(p0_gauge: float, v_tank: float, v0: float, v1: float, dv1_dxi: float, p_atm: float) -> float:
    """Paper eq. 2: dp1/dxi = -(p0*v_tank + p_atm*v0)/(v_tank + v1)^2 * dv1/dxi (Pa per unit xi)."""
    return -((p0_gauge + p_atm) * v_tank + p_atm * v0) / (v_tank + v1) ** 2 * dv1_dxi


def eq10_pressure(p0_gauge: float, v_tank: float, area: float, l0: float, wall: float, p_atm: float) -> float:
    """Paper eq. 10, absolute pressure of the linear actuator touching a wall at L."""
    return ((p0_gauge + p_atm) * v_tank + p_atm * area * l0) / (v_tank + area * (l0 + wall))


def eq11_resolution(p0_gauge: float, v_tank: float, area: float, l0: float, wall: float, p_atm: float) -> float:
    """Paper eq. 11, dp1/dL of the linear actuator (Pa/m); assumes the wall is reached."""
    return -((p0_gauge + p_atm) * v_tank + p_atm * area * l0) / (v_tank + area * (l0 + wall)) ** 2 * area
