"""The figures of the parts the paper's rig names (Methods: Festo VEAB regulator, Brooks
SLA5850 flow controller, Honeywell HAFBLF0750 flow sensor, Honeywell SSC +-34.5 and
+-103.4 kPa, NXP MPX5100DP and MPX4250DP pressure sensors), each with where it comes from.

``status`` says how far to trust a figure:

- ``datasheet``: read in the manufacturer's datasheet text (title and revision given);
- ``paper``: stated in the reference paper (section given);
- ``recalled``: a figure of the named datasheet that could not be read here; treat it as
  an assumption, varied over ``range``;
- ``assumption``: no published figure; the value and the ``range`` it is varied over are
  ours, with the reason.

A datasheet's "max error" or accuracy is a bound; the budget draws it as a rectangular
distribution over +-bound (GUM, JCGM 100:2008, 4.3.7). Nothing here is set from an
accuracy the report compares with. Profiles copy the figures their parts carry into their
``budget`` block (common/budget.py); ``python -m lab bench budget`` propagates them.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Figure:
    part: str
    quantity: str
    value: float
    unit: str
    status: str  # datasheet | paper | recalled | assumption
    source: str
    range: tuple[float, float] | None = None  # what an uncertain figure is varied over
    drawn: str = ""  # per session | per target | per cycle | per sample | not drawn (why)


SSC_34 = "Honeywell SSCDRRN005PDAA5 (+-34.5 kPa)"
SSC_103 = "Honeywell SSCDRRN015PDAA5 (+-103.4 kPa)"
MPX5100 = "NXP MPX5100DP (0-100 kPa)"
MPX4250 = "NXP MPX4250DP (0-250 kPa)"
HAF = "Honeywell HAFBLF0750CAAX5 (+-750 SCCM)"
MFC = "Brooks SLA5850 mass flow controller"
VEAB = "Festo VEAB-L-26-D13-Q4-V1-1R1 regulator (-100..100 kPa)"
HAND = "target set by hand with a caliper"

FIGURES: tuple[Figure, ...] = (
    Figure(SSC_34, "accuracy (non-linearity, hysteresis, repeatability), BFSL", 0.25, "% FSS", "paper",
           "paper, Discussion (+-0.25 % FSS, +-0.1725 kPa)",
           drawn="not drawn per cycle: the paper's own cycle-to-cycle sd of P_eq (cycling test, 0.04 kPa) "
           "bounds the part of it that repeats per cycle, and that sd is already carried by the regulator's "
           "repeatability (set from it); its non-linearity is fixed and folds into the calibration"),
    Figure(SSC_34, "total error band, 0-50 C (zero, span, thermal)", 2.0, "% FSS", "recalled",
           "Honeywell TruStability SSC series datasheet", (1.0, 2.0),
           drawn="zero: per session (sensor_zero_kpa = 2 % of 69 kPa = 1.38 kPa), removed by the per-cycle "
           "offset; span: not drawn (the same unit in calibration and test)"),
    Figure(SSC_34, "compensated range", 34.5, "kPa", "paper",
           "paper, Methods 'Sorting experiment' (uncompensated up to 40.7 kPa)",
           drawn="not drawn: the sorting gripper reads 34-35.4 kPa, at or beyond it (no figure for the error there)"),
    Figure(SSC_34, "noise per sample (sd)", 0.07, "kPa", "paper",
           "the sorting readings' sd (paper, Methods 'Sorting experiment'), existing sensor.noise_sd_kpa",
           drawn="per sample"),
    Figure(SSC_34, "resolution (16-bit DAQ, 4 V over 69 kPa)", 0.0053, "kPa", "datasheet",
           "NI USB-6212 (16 bit, +-10 V) named in the paper's Methods; existing sensor.quantum_kpa",
           drawn="per sample"),
    Figure(SSC_103, "total error band, 0-50 C", 2.0, "% FSS", "recalled",
           "Honeywell TruStability SSC series datasheet", (1.0, 2.0),
           drawn="zero per session (4.1 kPa), removed by the per-cycle offset"),
    Figure(MPX5100, "maximum error over 0-85 C (incl. offset, span, linearity, hysteresis)", 2.5, "% VFSS",
           "datasheet", "NXP MPX5100 data sheet, Rev. 14, 12/2018, Features",
           drawn="zero per session (2.5 kPa), removed by the per-cycle offset"),
    Figure(MPX4250, "maximum error over 0-85 C", 1.4, "% VFSS", "datasheet",
           "Freescale MPX4250 data sheet, Rev 7, 1/2009, Features and Table 1",
           drawn="tank sensor of the sorting rig; not in the distance methods"),
    Figure(MPX4250, "offset stability", 0.5, "% VFSS", "datasheet", "Freescale MPX4250 data sheet, Rev 7, Table 1",
           drawn="tank sensor; not in the distance methods"),
    Figure(HAF, "compensated temperature range", 50.0, "C (0-50)", "datasheet",
           "Honeywell Zephyr HAF series +-50 to +-750 SCCM datasheet (32308684)", drawn="not drawn"),
    Figure(HAF, "repeatability and hysteresis of reading", 0.5, "% reading", "assumption",
           "no figure found for the +-750 SCCM analog part; the series' total error band is stated only as "
           "'as low as 0.25 % FSS'", (0.25, 1.0),
           drawn="per cycle (flow_sensor_of_reading); its zero is removed by the per-cycle flow offset"),
    Figure(HAF, "noise per sample (sd)", 0.004, "SLPM", "assumption",
           "existing flow_sensor.noise_sd_slpm; integrated over 30 s it moves V_eq by about 0.01 ml, so "
           "halving or doubling it changes no method", (0.002, 0.008), drawn="per sample"),
    Figure(MFC, "accuracy of rate (20-100 % FS)", 0.9, "% of rate", "recalled",
           "Brooks SLA5800 series product data sheet", (0.7, 1.0),
           drawn="per session (flow_controller_of_rate = 0.009)"),
    Figure(MFC, "repeatability of rate", 0.2, "% of rate", "recalled", "Brooks SLA5800 series product data sheet",
           (0.1, 0.3), drawn="per cycle: the existing circuit.flow_repeatability (0.3 % sd, assumed) covers it"),
    Figure(VEAB, "repeatability from one setting to the next (sd)", 0.08, "kPa", "paper",
           "set from the paper's cycling test (P_eq sd about 0.04 kPa, Results 'Size sensing') through "
           "dP_eq/dP0 = 0.51: existing circuit.regulator_repeatability_kpa", drawn="per cycle (per setting)"),
    Figure(VEAB, "setpoint error between sessions", 0.05, "kPa", "assumption",
           "no datasheet figure found here; a fresh session re-sets the regulator at the same setpoint, so its "
           "linearity error repeats and only its drift (temperature, supply) changes the output", (0.0, 0.1),
           drawn="per session (regulator_setpoint_kpa)"),
    Figure(HAND, "placement of the plate relative to the actuator's rest position", 0.5, "mm", "assumption",
           "the caliper itself reads to +-0.02 mm; setting the bar by hand against it, square to the actuator, "
           "is the larger part", (0.25, 1.0), drawn="per placement (placement_mm)"),
)


def figures_of(part: str) -> list[Figure]:
    return [f for f in FIGURES if f.part == part]
