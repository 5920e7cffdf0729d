"""Flow elements and wall heat exchange of the gas network, as the field models them.

- Valve: ISO 6358-1 (sonic conductance C, critical pressure ratio b). The mass flow is
  ``rho_ANR * C * p_up * sqrt(T_ANR / T_up)`` when choked (``p_dn / p_up <= b``), times
  the elliptic factor ``sqrt(1 - ((r - b) / (1 - b))^2)`` when subsonic, and linear in
  the pressure drop above ``r = 0.999`` (ISO 6358-1:2013's laminar region, which also
  keeps the flow Lipschitz at equilibrium, so the integrator never meets the square
  root's infinite slope). ANR reference: 100 kPa, 20 degC (ISO 8778).
- Hose: Darcy-Weisbach in a round bore at the mean density, laminar (f = 64/Re) or
  turbulent (Blasius, f = 0.3164 Re^-0.25), whichever gives the larger friction: the two
  cross at Re ~ 1190, so the flow is laminar below and Blasius above.
- Wall heat exchange: Newton's law with a wall time constant tau per volume: at
  constant volume and amount the gas temperature relaxes to the wall's (kept at the
  reference temperature) as ``dT/dt = (T_w - T) / tau``. ``tau`` comes from a published
  correlation for the volume's geometry (functions below), never from a reading.

Amounts are in the network's unit ``m = n R T0`` (Pa*m^3) with T0 = 293.15 K, the ANR
temperature, so a flow of q standard (ANR) m^3/s is ``P_ANR * q`` of m per second.
"""

from __future__ import annotations

import math

GAMMA = 1.4  # ratio of specific heats of air
T0_K = 293.15  # reference (wall and ambient) temperature, the ANR 20 degC
P_ANR = 100_000.0  # Pa, ISO 8778 reference pressure
R_AIR = 287.05  # J/(kg K)
CV_AIR = R_AIR / (GAMMA - 1.0)  # J/(kg K)
CP_AIR = GAMMA * CV_AIR
MU_AIR = 1.81e-5  # Pa*s at 20 degC
K_AIR = 0.0257  # W/(m K) at 20 degC
LAMINAR_RATIO = 0.999  # ISO 6358-1:2013: above this pressure ratio the flow is laminar
DM3_PER_S_BAR = 1e-3 / 1e5  # m^3/(s*Pa) per dm^3/(s*bar)


def iso6358_factor(ratio: float, b: float) -> float:
    """Flow as a fraction of the choked flow at pressure ratio ``p_dn / p_up`` (0..1)."""
    if ratio <= b:
        return 1.0
    if ratio <= LAMINAR_RATIO:
        x = (ratio - b) / (1.0 - b)
        return math.sqrt(max(1.0 - x * x, 0.0))
    x = (LAMINAR_RATIO - b) / (1.0 - b)
    return (1.0 - ratio) / (1.0 - LAMINAR_RATIO) * math.sqrt(1.0 - x * x)


def iso6358_amount_flow(c_m3_per_s_pa: float, b: float, p_a: float, p_b: float, theta_a: float = 1.0,
                        theta_b: float = 1.0) -> float:
    """Amount flow a -> b (m units per second, signed) through an ISO 6358 element.

    ``theta`` is each side's temperature over T0: the upstream side's sets the flow.
    """
    if p_a >= p_b:
        up, dn, th = p_a, p_b, theta_a
        sign = 1.0
    else:
        up, dn, th = p_b, p_a, theta_b
        sign = -1.0
    if up <= 0.0:
        return 0.0
    q_anr = c_m3_per_s_pa * up * iso6358_factor(dn / up, b) / math.sqrt(th)
    return sign * P_ANR * q_anr


def hose_amount_flow(bore_m: float, length_m: float, p_a: float, p_b: float, theta: float = 1.0) -> float:
    """Amount flow a -> b (m units per second, signed) through a round hose (Darcy-Weisbach)."""
    dp = p_a - p_b
    if dp == 0.0:
        return 0.0
    p_mean = 0.5 * (p_a + p_b)
    rho = p_mean / (R_AIR * T0_K * theta)
    adp = abs(dp)
    v_lam = adp * bore_m**2 / (32.0 * MU_AIR * length_m)
    v_turb = (adp / (0.1582 * length_m * rho**0.75 * MU_AIR**0.25 * bore_m**-1.25)) ** (1.0 / 1.75)
    v = min(v_lam, v_turb)
    area = math.pi * bore_m**2 / 4.0
    return math.copysign(p_mean * v * area / theta, dp)


# ----------------------------------------------------------- wall time constants
def _churchill_chu(rayleigh: float, prandtl: float = 0.71) -> float:
    """Nusselt number of natural convection along a vertical wall, any Rayleigh number
    (Churchill & Chu 1975, Int. J. Heat Mass Transfer 18:1323; Incropera & DeWitt,
    Fundamentals of Heat and Mass Transfer, eq. 9.26)."""
    return (0.825 + 0.387 * rayleigh ** (1 / 6) / (1 + (0.492 / prandtl) ** (9 / 16)) ** (8 / 27)) ** 2


def tank_wall_time_s(volume_m3: float, p_abs: float, delta_t_k: float = 10.0, aspect: float = 2.0) -> float:
    """Wall time constant of a closed cylindrical tank whose gas exchanges heat with its
    wall by natural convection (Churchill-Chu on the side wall, the same coefficient on the
    ends): ``tau = rho cv V / (h A)``.

    ``aspect`` is the tank's length over its diameter (2 assumed: the paper names the
    tanks, not their dimensions); ``delta_t_k`` the gas-wall temperature difference the
    coefficient is evaluated at (10 K assumed; a tank that discharges into a gripper
    cools by 10-15 K adiabatically). The coefficient grows only as delta_t^(1/3)..^(1/4).
    """
    d = (4.0 * volume_m3 / (math.pi * aspect)) ** (1 / 3)
    length = aspect * d
    area = math.pi * d * length + 2 * math.pi * d * d / 4
    rho = p_abs / (R_AIR * T0_K)
    nu = MU_AIR / rho
    alpha = K_AIR / (rho * CP_AIR)
    rayleigh = 9.81 * delta_t_k / T0_K * length**3 / (nu * alpha)
    h = _churchill_chu(rayleigh) * K_AIR / length
    return rho * CV_AIR * volume_m3 / (h * area)


def bore_wall_time_s(bore_m: float, p_abs: float) -> float:
    """Wall time constant of gas at rest in a long round bore: conduction to an
    isothermal wall, slowest mode of the cylinder, ``tau = (r / 2.405)^2 / alpha`` with
    alpha = k / (rho cv) (Carslaw & Jaeger, Conduction of Heat in Solids, sec. 7.4)."""
    rho = p_abs / (R_AIR * T0_K)
    alpha = K_AIR / (rho * CV_AIR)
    return (0.5 * bore_m / 2.405) ** 2 / alpha


def gap_wall_time_s(gap_m: float, p_abs: float) -> float:
    """Wall time constant of gas in a flat chamber of width ``gap_m`` between two
    isothermal walls (an elastomer finger's chamber): slowest slab mode,
    ``tau = (gap / pi)^2 / alpha`` (Carslaw & Jaeger, sec. 3.3)."""
    rho = p_abs / (R_AIR * T0_K)
    alpha = K_AIR / (rho * CV_AIR)
    return (gap_m / math.pi) ** 2 / alpha
