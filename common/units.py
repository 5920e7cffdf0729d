"""Unit conversions at the edges. Inside fluidsense everything is SI:
pressure in Pa (gauge unless a name says ``abs``), volume in m^3, time in s,
flow resistance in Pa*s/m^3, flow in standard m^3/s."""

from __future__ import annotations

P_ATM = 101_325.0  # Pa, standard atmosphere
KPA = 1_000.0  # Pa per kPa
ML = 1e-6  # m^3 per ml
LITRE = 1e-3  # m^3 per litre
MM = 1e-3  # m per mm
SLPM = 1e-3 / 60.0  # standard m^3/s per standard litre per minute


def kpa(pa):
    """Pa -> kPa (works on floats and numpy arrays)."""
    return pa / KPA


def pa(kpa_value):
    """kPa -> Pa."""
    return kpa_value * KPA
