"""What the pneumatic hardware is: circuit, actuator and pressure sensor.

These models describe physical parts. The simulated cell turns them into a plant; real
drivers use the parts that concern them (sensor range for fault checks, for example).
Units at this edge are the ones on datasheets (kPa, ml, mm, litres); the code converts to
SI once, through the properties.

Defaults come from the paper (Methods and the worked check in paper-numbers.md); where the
paper gives no number the default is a datasheet-typical value and says so.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from .models import StrictModel
from .units import KPA, LITRE, ML, MM, P_ATM

PositiveFloat = Annotated[float, Field(gt=0)]


class Circuit(StrictModel):
    """Regulator -> supply valve -> tank -> actuation valve -> resistor -> actuator.

    The actuation valve is a 3/2 valve: open connects tank and actuator, closed vents the
    actuator. Paper, Methods "Size sensing with soft gripper" and "Sorting experiment".
    """

    kind: Literal["tank"] = "tank"
    tank_l: PositiveFloat = Field(0.3, le=10, description="actuation tank volume (paper: three 0.1 L tanks)")
    resistor_pa_s_per_m3: float = Field(
        1.0e8, ge=0, le=1e11,
        description="flow resistor between actuation valve and actuator; the paper's gripper "
        "used an unspecified 'small' one (assumed 1e8); 5.7e8 is its slow configuration, "
        "7.3e9 its tank-method value")
    resistor_position: Literal["downstream", "upstream"] = Field(
        "downstream", description="downstream of the actuation valve the vent also passes the resistor")
    valve_resistance_pa_s_per_m3: PositiveFloat = Field(
        3.0e7, le=1e11, description="open solenoid valve and fittings (datasheet-typical, assumed)")
    supply_resistance_pa_s_per_m3: PositiveFloat = Field(
        5.0e7, le=1e11, description="regulator + supply valve path that charges the tank (assumed)")
    valve_delay_s: float = Field(0.012, ge=0, le=1, description="solenoid switching delay (datasheet-typical)")
    regulator_tau_s: float = Field(0.05, gt=0, le=10, description="regulator first-order lag (assumed)")
    regulator_repeatability_kpa: float = Field(
        0.08, ge=0, le=10,
        description="sd of the regulator output from one charge to the next; 0.08 kPa gives the "
        "paper's cycle-to-cycle sd of P_eq (about 0.04 kPa, cycling test) through dP_eq/dP0 = 0.51")
    leak_resistance_pa_s_per_m3: float | None = Field(
        None, gt=0, description="actuator leak to atmosphere; none by default")
    p_atm_kpa: float = Field(P_ATM / KPA, gt=50, lt=120)

    @property
    def tank_m3(self) -> float:
        return self.tank_l * LITRE

    @property
    def p_atm(self) -> float:
        return self.p_atm_kpa * KPA


class GripperActuator(StrictModel):
    """Four PneuNet fingers on one line (paper, Fig. 1e-f).

    Free inflation: volume grows linearly with pressure. The finger tips close as the
    volume grows; a cylinder of diameter D is touched when the tip opening reaches D. After
    contact the fingers keep wrapping with ``wrap_ratio`` of their free compliance.
    Defaults follow the worked check in paper-numbers.md: v0 = 100 ml, 37 ml of growth at
    the empty-grip 34.6 kPa (1.07 ml/kPa), D = 20 mm barely touching, |dv1/dD| = 0.13 ml/mm
    (Table S1) which gives wrap_ratio 0.58.
    """

    kind: Literal["gripper"] = "gripper"
    v0_ml: PositiveFloat = Field(100.0, le=5000)
    compliance_ml_per_kpa: PositiveFloat = Field(1.07, le=100)
    open_mm: PositiveFloat = Field(120.0, le=500, description="tip opening at rest (assumed)")
    closing_mm_per_ml: PositiveFloat = Field(
        100.0 / 37.0, le=100, description="tip opening lost per ml of growth: 120 -> 20 mm over 37 ml")
    wrap_ratio: float = Field(0.58, ge=0, le=1)

    @property
    def v0(self) -> float:
        return self.v0_ml * ML

    @property
    def compliance(self) -> float:
        """m^3/Pa"""
        return self.compliance_ml_per_kpa * ML / KPA


class LinearActuator(StrictModel):
    """Linear extension actuator against a wall (paper, Methods "Modeling", eq. 6).

    The paper's parameter table is not in the text; these defaults are illustrative and
    chosen so that, from a 0.1 L tank at 50 kPa, the free tip extends about 33 mm.
    """

    kind: Literal["linear"] = "linear"
    area_mm2: PositiveFloat = Field(500.0, le=1e6)
    l0_mm: PositiveFloat = Field(100.0, le=1e4)
    stiffness_n_per_m: PositiveFloat = Field(300.0, le=1e9)

    @property
    def area(self) -> float:
        return self.area_mm2 * MM * MM

    @property
    def l0(self) -> float:
        return self.l0_mm * MM

    @property
    def v0(self) -> float:
        return self.area * self.l0


Actuator = Annotated[GripperActuator | LinearActuator, Field(discriminator="kind")]


class Sensor(StrictModel):
    """Gauge pressure sensor on the actuator tube, read by a 16-bit ADC.

    Defaults: Honeywell SSC +-103.4 kPa as in the paper's gripper tests; per-sample noise sd
    0.07 kPa (paper sorting readings); quantisation of a 16-bit +-10 V ADC reading a 4 V span
    over 206.8 kPa (0.016 kPa); a fixed offset that the per-cycle offset removes.
    """

    range_kpa: tuple[float, float] = (-103.4, 103.4)
    noise_sd_kpa: float = Field(0.07, ge=0, le=100)
    quantum_kpa: float = Field(0.016, ge=0, le=10)
    offset_kpa: float = Field(0.3, ge=-100, le=100)
    drift_kpa_per_h: float = Field(0.0, ge=-100, le=100)

    @model_validator(mode="after")
    def _range_ordered(self) -> Sensor:
        lo, hi = self.range_kpa
        if not lo < hi:
            raise ValueError(f"range_kpa must be [low, high] with low < high, got {list(self.range_kpa)}")
        return self


class Hardware(StrictModel):
    """Everything physical about one actuator set-up."""

    circuit: Circuit = Circuit()
    actuator: Actuator = GripperActuator()
    sensor: Sensor = Sensor()
    tank_sensor: Sensor = Sensor(offset_kpa=0.0)
