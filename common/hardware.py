"""What the pneumatic hardware is: circuit, actuator and sensors.

These models describe physical parts. The simulated cell turns them into a plant; real
drivers use the parts that concern them (sensor ranges for fault checks, which valves
exist and where each is safe). Units at this edge are the ones on datasheets (kPa, ml,
mm, litres, SLPM); the properties convert to SI once.

Defaults come from the paper (its Methods, and the worked check in paper-numbers.md);
where the paper gives no number the default is a datasheet-typical value or is derived
from a figure the paper does give, and the description says which.
"""

from __future__ import annotations

from typing import Annotated, Literal

from fluidsense.common.budget import PartsBudget
from fluidsense.common.models import Real, StrictModel
from fluidsense.common.units import KPA, LITRE, ML, MM, P_ATM, SLPM
from pydantic import Field, model_validator

PositiveFloat = Annotated[Real, Field(gt=0)]
Resistance = Annotated[Real, Field(gt=0, le=1e12)]
Ratio = Annotated[Real, Field(ge=0, le=1)]

# Valve names the sequencer knows. "Open" connects the source side towards the actuator;
# every circuit declares where each of its valves is safe (actuator vented, tank isolated).
SUPPLY, ACTUATE, VENT = "supply", "actuate", "vent"

# An ISO valve and a laminar resistor in series have the valve's outlet port and fittings
# between them: this volume (assumed; 0.1 % of the smallest actuator here). The simulated
# plant holds gas in it, and characterise counts it with the hose as the config's.
PORT_VOLUME_M3 = 0.2e-6


class Iso6358Valve(StrictModel):
    """The actuation valve as ISO 6358 describes it (sonic conductance, critical pressure
    ratio). No catalogue figure for the paper's SMC VDW250 or VX243 was found; the
    defaults are assumptions for a direct-operated valve of about 1.5 mm^2 effective
    area (C ~ 0.2 S/mm^2), varied over 0.2-0.6 and 0.15-0.5 in the fast-sorting band."""

    sonic_conductance_dm3_per_s_bar: Real = Field(0.3, gt=0, le=100)
    critical_ratio: Real = Field(0.3, ge=0, lt=1)


class Hose(StrictModel):
    """The line from the actuation valve to the actuator: its bore and length make a
    volume and a Darcy-Weisbach flow path; the pressure sensor sits at the valve end or at
    the actuator."""

    bore_mm: Real = Field(gt=0, le=50)
    length_m: Real = Field(gt=0, le=100)
    sensor_at: Literal["valve", "actuator"] = "valve"

    @property
    def volume_m3(self) -> float:
        return 3.141592653589793 * (self.bore_mm * MM) ** 2 / 4 * self.length_m


class Thermal(StrictModel):
    """Gas thermodynamics of the circuit's volumes: ``isothermal`` (the paper's eq. 1-9)
    or ``wall``: an energy balance per volume with Newton heat exchange to its wall. A
    wall time constant left empty comes from its correlation (simulator/elements.py):
    natural convection in the tank (Churchill-Chu) at ``wall_delta_t_k``, conduction
    across the actuator's chamber gap and the hose's bore."""

    model: Literal["isothermal", "wall"] = "isothermal"
    tank_wall_s: Real | None = Field(None, gt=0, le=1e6)
    actuator_wall_s: Real | None = Field(None, gt=0, le=1e6)
    line_wall_s: Real | None = Field(None, gt=0, le=1e6)
    wall_delta_t_k: Real = Field(10.0, gt=0, le=200, description="gas-wall difference of the tank correlation "
                                 "(assumed: a tank discharging into a gripper cools 10-15 K adiabatically)")
    tank_aspect: Real = Field(2.0, gt=0.2, le=20, description="tank length over diameter (assumed)")
    actuator_gap_mm: Real = Field(
        3.0, gt=0, le=100, description="chamber width of the actuator (assumed; PneuNet chambers are a few mm)")


class _CircuitBase(StrictModel):
    valve_resistance_pa_s_per_m3: Resistance = Field(
        3.0e7, description="open solenoid valve and fittings, laminar (assumed: valve catalogues give ISO 6358 "
        "figures, not a laminar resistance; ``valve`` replaces it)")
    valve: Iso6358Valve | None = Field(None, description="ISO 6358 valve in place of the laminar one")
    hose: Hose | None = None
    thermal: Thermal = Thermal()
    valve_delay_s: Real = Field(0.012, ge=0, le=1, description="solenoid switching delay (assumed)")
    resistor_pa_s_per_m3: Real = Field(1.0e8, ge=0, le=1e12, description="flow resistor before the actuator")
    resistor_position: Literal["downstream", "upstream"] = Field(
        "downstream", description="downstream of the actuation valve the vent also passes the resistor")
    flow_sensor: bool = Field(False, description="bidirectional flow sensor between resistor and actuator")
    leak_resistance_pa_s_per_m3: Real | None = Field(
        None, gt=0, le=1e15, description="actuator leak to atmosphere; none by default")
    p_atm_kpa: Real = Field(P_ATM / KPA, gt=50, lt=120)

    @property
    def p_atm(self) -> float:
        return self.p_atm_kpa * KPA

    @property
    def safe_valves(self) -> dict[str, bool]:
        """valve name -> open in the safe state"""
        raise NotImplementedError

    @property
    def venting_valves(self) -> tuple[str, ...]:
        """The valves whose safe positions vent the actuator; the supply valve's only
        isolates the tank, whose regulator is at 0 when nothing drives it."""
        return tuple(v for v in self.safe_valves if v != SUPPLY)

    @property
    def has_tank_sensor(self) -> bool:
        return True


class TankCircuit(_CircuitBase):
    """Method 1 (and 4): regulator -> supply valve -> tank -> actuation valve -> resistor
    -> actuator. The actuation valve is a 3/2 valve whose closed position vents the
    actuator (paper, Methods "Pressure control with pressure measurement", "Size sensing
    with soft gripper", "Sorting experiment"). With ``vent_valve`` the actuation valve is
    a 2/2 valve and a separate normally-open valve vents the actuator, so the actuator can
    also be held isolated (the suction cup's pull test).
    """

    kind: Literal["tank"] = "tank"
    tank_l: PositiveFloat = Field(0.3, le=10, description="actuation tank volume")
    supply_resistance_pa_s_per_m3: Resistance = Field(
        5.0e7, description="regulator + supply valve path that charges the tank (assumed)")
    regulator_tau_s: Real = Field(0.05, gt=0, le=10, description="regulator first-order lag (assumed)")
    regulator_repeatability_kpa: Real = Field(
        0.08, ge=0, le=10,
        description="sd of the regulator output from one charge to the next; 0.08 kPa gives the "
        "paper's cycle-to-cycle sd of P_eq (about 0.04 kPa, cycling test) through dP_eq/dP0 = 0.51")
    vent_valve: bool = False

    @property
    def tank_m3(self) -> float:
        return self.tank_l * LITRE

    @property
    def safe_valves(self) -> dict[str, bool]:
        valves = {SUPPLY: False, ACTUATE: False}
        if self.vent_valve:
            valves[VENT] = True
        return valves


class RegulatedCircuit(_CircuitBase):
    """Method 2, pressure control + flow measurement: regulator (with a buffer tank) ->
    actuation valve -> resistor -> flow sensor -> actuator (paper, Methods "Pressure
    control with flow measurement": 0.75 L buffer, 1.8e9 Pa*s/m^3, regulator 23.8 kPa)."""

    kind: Literal["regulated"] = "regulated"
    buffer_l: PositiveFloat = Field(0.75, le=100)
    supply_resistance_pa_s_per_m3: Resistance = 5.0e7
    regulator_tau_s: Real = Field(0.05, gt=0, le=10)
    regulator_repeatability_kpa: Real = Field(0.08, ge=0, le=10)
    resistor_pa_s_per_m3: Real = Field(1.8e9, ge=0, le=1e12)
    flow_sensor: bool = True

    @property
    def tank_m3(self) -> float:
        return self.buffer_l * LITRE

    @property
    def safe_valves(self) -> dict[str, bool]:
        return {ACTUATE: False}


class FlowControlledCircuit(_CircuitBase):
    """Method 3, flow control + pressure measurement: mass flow controller -> actuation
    valve -> resistor -> flow sensor -> actuator (paper, Methods "Flow control with
    pressure measurement"). The controller delivers its setpoint whatever the back
    pressure, so it is modelled as an ideal flow source."""

    kind: Literal["flow"] = "flow"
    max_flow_slpm: PositiveFloat = Field(1.0, le=100, description="mass flow controller range")
    flow_repeatability: Ratio = Field(
        0.003, description="relative sd of the delivered flow from one cycle to the next (assumed; "
        "MFC repeatability is typically 0.2-0.5 % of the setpoint)")
    resistor_pa_s_per_m3: Real = Field(1.8e9, ge=0, le=1e12)
    flow_sensor: bool = True

    @property
    def max_flow(self) -> float:
        return self.max_flow_slpm * SLPM

    @property
    def safe_valves(self) -> dict[str, bool]:
        return {ACTUATE: False}

    @property
    def has_tank_sensor(self) -> bool:
        return False


Circuit = Annotated[TankCircuit | RegulatedCircuit | FlowControlledCircuit, Field(discriminator="kind")]


# ------------------------------------------------------------------ actuators
class _Compliant(StrictModel):
    v0_ml: PositiveFloat = Field(description="internal volume at atmospheric pressure, tubing included")
    compliance_ml_per_kpa: PositiveFloat = Field(description="free dv/dp")
    response_s: Real = Field(
        0.0, ge=0, le=10, description="mechanical time constant of free inflation: the volume follows "
        "the P-V law through a dashpot (0: quasi-static, the volume is always on the law)")

    @property
    def damping(self) -> float:
        """Pa*s/m^3: the dashpot that gives ``response_s`` on the free P-V line."""
        return self.response_s / self.compliance

    @property
    def v0(self) -> float:
        return self.v0_ml * ML

    @property
    def compliance(self) -> float:
        """m^3/Pa"""
        return self.compliance_ml_per_kpa * ML / KPA


class GripperActuator(_Compliant):
    """Soft fingers closing on an object (paper, Fig. 1e-f; Fig. retrofit 2 f-k).

    Free inflation: the volume grows linearly with pressure and the finger tips close,
    ``closing_mm_per_ml`` per ml of growth from ``open_mm``; an object of size D is
    touched when the tip opening reaches D. After contact the fingers keep wrapping with
    ``wrap_ratio`` of their free compliance. A ``vacuum`` gripper closes as its volume
    shrinks under negative pressure.

    Defaults: the four-finger PneuNet gripper, from the worked check in paper-numbers.md:
    v0 = 100 ml, 37 ml of growth at the empty-grip 34.6 kPa (1.07 ml/kPa), D = 20 mm barely
    touching (120 -> 20 mm over 37 ml), |dv1/dD| = 0.13 ml/mm (Table S1) -> wrap_ratio 0.58.
    """

    kind: Literal["gripper"] = "gripper"
    v0_ml: PositiveFloat = Field(100.0, le=5000)
    compliance_ml_per_kpa: PositiveFloat = Field(1.07, le=100)
    open_mm: PositiveFloat = Field(120.0, le=500, description="tip opening at rest (assumed)")
    closing_mm_per_ml: PositiveFloat = Field(100.0 / 37.0, le=100)
    wrap_ratio: Ratio = 0.58
    drive: Literal["positive", "vacuum"] = "positive"
    push_ratio: Ratio = Field(
        0.9, description="compliance kept while one finger pushes an off-centre object towards the "
        "centre (sliding friction only; assumed)")
    force_area_mm2: PositiveFloat = Field(
        300.0, le=1e6, description="grip force per pressure above the contact pressure, which squeezes soft "
        "objects (assumed)")


class BendingActuator(_Compliant):
    """A single PneuNet bending actuator whose tip moves towards a surface (paper, Fig. 1a-d
    and Fig. 2). Tip travel grows ``travel_mm_per_ml`` per ml of growth; once the tip meets
    a rigid surface the actuator keeps ``contact_ratio`` of its free compliance (it
    balloons). A soft surface yields to the tip force ``force_area * (p - p_contact)`` by
    force over its stiffness, and the tip follows it.

    Defaults: v0 25 ml and 1.0 ml/kPa put a 0.1 L tank at 49.9 kPa at about 20 kPa with
    ~29 ml of standard air in the actuator (the paper's free-actuation snapshot at 28.7 ml);
    3 mm/ml lets the tip reach the plate at h = 40 mm; contact_ratio 0.77 gives the paper's
    average resolution, about 0.04 kPa/mm. Tip stiffness and force area are assumed.
    """

    kind: Literal["bending"] = "bending"
    v0_ml: PositiveFloat = Field(25.0, le=5000)
    compliance_ml_per_kpa: PositiveFloat = Field(1.0, le=100)
    travel_mm_per_ml: PositiveFloat = Field(3.0, le=1000)
    contact_ratio: Ratio = 0.77
    force_area_mm2: PositiveFloat = Field(
        150.0, le=1e6, description="tip force per pressure above the contact pressure (assumed)")


class SuctionCup(_Compliant):
    """A suction cup on a silicone sample (paper, Fig. retrofit 2 a-e; Methods "Suction
    cup"). Under vacuum the cup itself and the attached sample are pulled in: the volume
    lost is ``compliance * |p|`` plus ``sample_bulge_ml_kpa / E * |p|`` for a sample of
    modulus E. Pulling the cup with force F grows its volume by ``pull_compliance * F``;
    it detaches when F exceeds |p| * ``area``.

    Defaults are illustrative (the paper gives no cup volume): a 5 ml cup; the bulge
    constant is chosen so that P_eq from a 15 ml tank at -62 kPa spans a few kPa over the
    four samples (paper Table 1: 1.3-5.9 kPa across actuators); the area and pull
    compliance reproduce the paper's detachment at dP ~ 1.2 kPa with 4.53 N on OO-30.
    """

    kind: Literal["suction"] = "suction"
    v0_ml: PositiveFloat = Field(5.0, le=1000)
    compliance_ml_per_kpa: PositiveFloat = Field(0.01, le=100, description="the cup's own collapse")
    sample_bulge_ml_kpa: PositiveFloat = Field(
        0.6, le=1e4, description="ml of sample drawn in per kPa of vacuum, times the sample modulus in kPa")
    area_mm2: PositiveFloat = Field(100.0, le=1e5)
    pull_compliance_ml_per_n: PositiveFloat = Field(0.0166, le=100)


class MuscleActuator(_Compliant):
    """An artificial muscle rotating a joint towards a stopper (paper, Fig. retrofit 1 a-f).
    The joint turns ``deg_per_ml`` per ml of growth until the stopper at theta; then the
    muscle keeps ``blocked_ratio`` of its compliance (a filament actuator still deforms
    freely sideways; a McKibben can only expand radially, so its ratio is small)."""

    kind: Literal["muscle"] = "muscle"
    v0_ml: PositiveFloat = Field(1.0, le=5000)
    compliance_ml_per_kpa: PositiveFloat = Field(0.02, le=100)
    deg_per_ml: PositiveFloat = Field(20.0, le=1e5)
    blocked_ratio: Ratio = 0.2


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


Actuator = Annotated[GripperActuator | BendingActuator | SuctionCup | MuscleActuator | LinearActuator,
                     Field(discriminator="kind")]


# -------------------------------------------------------------------- sensors
class Sensor(StrictModel):
    """Gauge pressure sensor read by a 16-bit ADC.

    Defaults: Honeywell SSC +-103.4 kPa as in the paper's gripper tests; per-sample noise sd
    0.07 kPa (the paper's sorting readings); quantisation of a 16-bit +-10 V ADC reading a 4 V
    span over 206.8 kPa (0.016 kPa); a fixed offset that the per-cycle offset removes.
    """

    range_kpa: tuple[Real, Real] = (-103.4, 103.4)
    noise_sd_kpa: Real = Field(0.07, ge=0, le=100)
    quantum_kpa: Real = Field(0.016, ge=0, le=10)
    offset_kpa: Real = Field(0.3, ge=-100, le=100)
    drift_kpa_per_h: Real = Field(0.0, ge=-1000, le=1000)

    @model_validator(mode="after")
    def _range_ordered(self) -> Sensor:
        lo, hi = self.range_kpa
        if not lo < hi:
            raise ValueError(f"range_kpa must be [low, high] with low < high, got {list(self.range_kpa)}")
        return self


class FlowSensor(StrictModel):
    """Bidirectional flow sensor, standard litres per minute (Honeywell HAFBLF0750, +-750
    SCCM, as in the paper). Noise and offset are assumed (datasheet-typical)."""

    range_slpm: tuple[Real, Real] = (-0.75, 0.75)
    noise_sd_slpm: Real = Field(0.004, ge=0, le=100)
    quantum_slpm: Real = Field(0.0005, ge=0, le=10)
    offset_slpm: Real = Field(0.002, ge=-100, le=100)

    @model_validator(mode="after")
    def _range_ordered(self) -> FlowSensor:
        lo, hi = self.range_slpm
        if not lo < hi:
            raise ValueError(f"range_slpm must be [low, high] with low < high, got {list(self.range_slpm)}")
        return self


class Hardware(StrictModel):
    """Everything physical about one actuator set-up."""

    circuit: Circuit = TankCircuit()
    actuator: Actuator = GripperActuator()
    sensor: Sensor = Sensor()
    tank_sensor: Sensor = Sensor(offset_kpa=0.0)
    flow_sensor: FlowSensor = FlowSensor()
    budget: PartsBudget = PartsBudget()

    @property
    def channels(self) -> tuple[str, ...]:
        ch = ["p_act"]
        if self.circuit.has_tank_sensor:
            ch.append("p_tank")
        if self.circuit.flow_sensor:
            ch.append("flow")
        return tuple(ch)
