"""An actuator profile: its hardware, its safe envelope, its cycle and its calibration
protocol (config/profiles/*.yaml)."""

from __future__ import annotations

from typing import Literal

from fluidsense.common.budget import PartsBudget
from fluidsense.common.hardware import (
    Actuator,
    Circuit,
    FlowSensor,
    GripperActuator,
    Hardware,
    Sensor,
    TankCircuit,
)
from fluidsense.common.models import FieldError, Integer, Real, StrictModel
from fluidsense.common.scenes import Scene
from fluidsense.common.units import KPA
from pydantic import Field, model_validator


class Window(StrictModel):
    """A measurement window, in seconds after the actuation valve opens."""

    name: str = Field(min_length=1, max_length=40)
    start_s: Real = Field(ge=0)
    end_s: Real = Field(gt=0)

    @model_validator(mode="after")
    def _ordered(self) -> Window:
        if not self.end_s > self.start_s:
            raise ValueError(f"end_s ({self.end_s}) must be after start_s ({self.start_s})")
        return self


class FlowProfile(StrictModel):
    """Flow-control programme (paper, Methods "Flow control with pressure measurement"):
    ramp from 0 to ``flow_slpm`` in ``ramp_s``, hold ``hold_s``, then zero."""

    flow_slpm: Real = Field(0.3, gt=0, le=100)
    ramp_s: Real = Field(5.0, ge=0, le=600)
    hold_s: Real = Field(4.0, ge=0, le=600)


class SequenceConfig(StrictModel):
    """One actuation cycle: CHARGE -> ISOLATE -> ACTUATE -> HOLD -> VENT.

    Methods (paper, Methods "Distance sensing"): ``tank`` charges a tank to P0 and measures
    the pressure the actuator settles at (method 1; with a free-air reference it also gives
    the pressure-time features of method 4); ``pressure_flow`` holds the actuator at a
    regulated P0 and integrates the flow into it (method 2); ``flow_control`` feeds a flow
    profile and measures the pressure (method 3). A zero-length ISOLATE is skipped.
    """

    method: Literal["tank", "pressure_flow", "flow_control"] = "tank"
    p0_kpa: Real = Field(63.0, ge=-100, le=1000,
                          description="tank charge pressure (tank) or regulated pressure (pressure_flow)")
    charge_s: Real = Field(10.0, gt=0, le=600)
    isolate_s: Real = Field(10.0, ge=0, le=600)
    actuate_s: Real = Field(20.0, gt=0, le=3600)
    vent_s: Real = Field(10.0, gt=0, le=600)
    offset_s: Real = Field(1.0, gt=0, le=60, description="sensor offset: mean of this long before opening")
    settle_window_s: Real = Field(
        15.0, gt=0, le=120, description="the valve opens only once the vented actuator has read flat (its drift "
        "within the noise) over this long (at most charge_s + isolate_s): a tube still venting would bias the "
        "offset and the gas the actuator starts with")
    settle_timeout_s: Real = Field(
        180.0, ge=0, le=3600, description="how long past the planned opening to wait for the actuator to settle "
        "before the cycle is refused ('not settled'); 0 opens without the check")
    settle_floor_kpa: Real = Field(
        0.003, ge=0, le=10, description="drift over settle_window_s always taken as flat (a very quiet sensor "
        "would otherwise wait for drifts no measurement can see)")
    charge_tolerance_kpa: Real | None = Field(
        None, gt=0, le=100, description="the charge ends, and the valve opens, only on a tank (tank) or buffer "
        "(pressure_flow) whose sensor reads P0 within this, averaged over offset_s: a charge that has not got "
        "there goes on (up to charge_timeout_s more), and a tank that has fallen short by the opening refuses "
        "the cycle ('not charged'), since a short charge gives a P_eq as wrong as any contact. None: the "
        "profile's P0 margin, at least 0.05 kPa (the "
        "tank sensor's offset and quantum, 4 sd of the regulator's repeatability and 6 sd of the noise, about "
        "1.1 kPa with the defaults). Give more for a regulator whose setpoint is off by a steady amount (the "
        "free-air reference, taken at the same setpoint, cancels that)")
    charge_timeout_s: Real = Field(
        30.0, ge=0, le=3600, description="how long past charge_s to go on charging a tank that does not read P0 "
        "yet (the first cycle of a session starts from an empty tank) before the cycle is refused ('not "
        "charged': a supply below P0, a blocked line)")
    windows: list[Window] = Field(default_factory=lambda: [Window(name="eq", start_s=4.0, end_s=5.0)],
                                  min_length=1, max_length=16)
    flow_window: Window | None = Field(
        None, description="integrate the flow into the actuator over this window (pressure_flow: V_eq)")
    flow_profile: FlowProfile | None = Field(None, description="flow_control: the flow programme")
    isolate_actuator_at_s: Real | None = Field(
        None, gt=0, description="close the actuation valve this long after opening and hold the actuator "
        "isolated until VENT (needs a circuit with a separate vent valve)")
    contact_threshold_kpa: Real = Field(0.5, gt=0, le=100, description="dP level for t_c by threshold")
    onset_kpa: Real = Field(0.15, gt=0, le=100, description="dP level taken as the first rise (t_c at onset): "
                             "about five times the noise of a smoothed dP")
    smoothing_samples: Integer = Field(21, ge=3, le=1001, description="local quadratic regression span")
    align_rise_kpa: tuple[Real, Real] | Literal["auto"] | None = Field(
        "auto", description="before dP is taken, shift each cycle in time so that its rise through two levels "
        "(away from atmosphere, offset removed) lines up with the free-air reference's. Removes the valve's "
        "timing from dP: a polled driver (UR box, Modbus) switches it a few ms after the sample the command was "
        "decided on, by as many ms as the PC was busy, and on the first rise a ms is worth tenths of a kPa. "
        "'auto' (default): 2 % and 8 % of the reference's level in the first window (at least 5 and 10 times its "
        "noise there); [lo, hi]: those levels in kPa. Contact below the upper level is not seen by dP, and no "
        "contact time is earlier than the reference reaches it. None: time since the commanded opening, as a "
        "hardware-timed cell whose valve switches on the sample clock knows it")
    eq_sd_kpa: Real | None = Field(
        None, ge=0, le=100, description="cycle-to-cycle sd of the free-air equilibrium (first window), as "
        "measured on the rig. None: the circuit's repeatability carried to the equilibrium (regulator: "
        "circuit.regulator_repeatability_kpa x P_eq/P0, the paper's 0.08 kPa giving its cycling test's "
        "0.04 kPa; flow: circuit.flow_repeatability x the absolute pressure). A grasp's object needs its "
        "equilibrium dP beyond 4 sd of the difference of two cycles (4 x sqrt(2) x this)")

    @model_validator(mode="after")
    def _consistent(self) -> SequenceConfig:
        if self.offset_s > self.charge_s + self.isolate_s:
            raise ValueError(f"offset_s ({self.offset_s}) must fit before the valve opens "
                             f"(charge_s + isolate_s = {self.charge_s + self.isolate_s})")
        for w in [*self.windows, *([self.flow_window] if self.flow_window else [])]:
            if w.end_s > self.actuate_s:
                raise ValueError(f"window {w.name!r} ends at {w.end_s} s, after the valve closes "
                                 f"(actuate_s = {self.actuate_s})")
        names = [w.name for w in self.windows]
        if len(set(names)) != len(names):
            raise ValueError(f"window names must be unique, got {names}")
        if self.method == "flow_control" and self.flow_profile is None:
            raise ValueError("method flow_control needs a flow_profile")
        if self.method == "pressure_flow" and self.flow_window is None:
            raise ValueError("method pressure_flow needs a flow_window to integrate over")
        if self.method == "tank" and self.isolate_s == 0:
            raise ValueError("method tank needs isolate_s > 0 (the tank must be isolated before opening)")
        if isinstance(self.align_rise_kpa, tuple) and not 0 < self.align_rise_kpa[0] < self.align_rise_kpa[1] <= 100:
            raise ValueError(f"align_rise_kpa must be [lo, hi] with 0 < lo < hi <= 100, got {list(self.align_rise_kpa)}")
        if self.isolate_actuator_at_s is not None and self.isolate_actuator_at_s >= self.actuate_s:
            raise ValueError("isolate_actuator_at_s must come before the end of actuate_s")
        return self

    @property
    def p0_pa(self) -> float:
        return self.p0_kpa * KPA

    @property
    def settle_s(self) -> float:
        """The settle test's window: a fast cycle (the sorting gripper's 2.5 s before
        opening) is not made to wait for a window longer than its own preparation."""
        return min(self.settle_window_s, self.charge_s + self.isolate_s)


class Limits(StrictModel):
    """Pressure envelope of the actuator (gauge). Nothing may command beyond it."""

    max_kpa: Real = Field(gt=-100, le=1000)
    min_kpa: Real = Field(ge=-101, le=1000)

    @model_validator(mode="after")
    def _ordered(self) -> Limits:
        if not self.min_kpa < self.max_kpa:
            raise ValueError(f"min_kpa ({self.min_kpa}) must be below max_kpa ({self.max_kpa})")
        return self

    @property
    def max_pa(self) -> float:
        return self.max_kpa * KPA

    @property
    def min_pa(self) -> float:
        return self.min_kpa * KPA


class CalibrationPlan(StrictModel):
    """How this profile is calibrated by default (the paper's protocol for it)."""

    scene: Scene = Field(description="scene whose target field is varied")
    target: str = Field(min_length=1, description="the scene field that is the sensing target")
    values: list[Real] = Field(min_length=2, max_length=200)
    cycles: Integer = Field(8, ge=1, le=1000)
    drop_first: Integer = Field(1, ge=0, le=100)
    feature: Literal["p_eq", "v_eq", "dp_eq", "dp_max", "t_c_slope", "t_c_threshold", "t_c2"] = "p_eq"
    fit: Literal["linear", "poly2", "poly3"] = "linear"

    @model_validator(mode="after")
    def _target_exists(self) -> CalibrationPlan:
        if self.target not in type(self.scene).model_fields:
            raise ValueError(f"target {self.target!r} is not a field of scene {self.scene.kind!r}")
        if self.drop_first >= self.cycles:
            raise ValueError(f"drop_first ({self.drop_first}) leaves no cycle of {self.cycles}")
        return self


class FittedNumber(StrictModel):
    """One number ``fluidsense characterise`` measured on a rig: the profile field it set,
    its value and 95 % interval in the field's own unit, and how it was obtained."""

    field: str = Field(min_length=1, max_length=120, description="dotted profile field, e.g. actuator.v0_ml")
    value: Real
    lo95: Real
    hi95: Real
    unit: str = Field("", max_length=40)
    how: str = Field("", max_length=2000, description="what was fitted to what, and what it assumes")

    @model_validator(mode="after")
    def _ordered(self) -> FittedNumber:
        if not self.lo95 <= self.value <= self.hi95:
            raise ValueError(f"{self.field}: value {self.value} outside its interval [{self.lo95}, {self.hi95}]")
        return self


class ContactReading(StrictModel):
    """What the rig read at one known target (or in free air, ``size`` None) during the
    contact step of ``fluidsense characterise --targets``, and what the fitted law gives."""

    size: Real | None = Field(description="the target's size in the scene's unit; None: nothing there")
    cycles: Integer = Field(ge=1, le=10_000)
    cycle_ids: list[Integer] = Field(default_factory=list, max_length=10_000)
    p_eq_kpa: Real = Field(description="mean equilibrium (first window), oriented away from atmosphere")
    p_eq_sd_kpa: Real = Field(ge=0, description="its cycle-to-cycle sd")
    dp_eq_kpa: Real | None = Field(None, description="over the free cycles' mean")
    p_contact_kpa: Real | None = Field(None, description="mean pressure at which the rise left the free one")
    p_contact_sd_kpa: Real | None = Field(None, ge=0)
    p_contact_note: str | None = Field(None, max_length=1000, description="why no contact pressure was read")
    t_c_threshold_s: Real | None = Field(None, description="mean contact time the controller read (threshold)")
    law_dp_eq_kpa: Real | None = Field(None, description="dP_eq of the fitted law")
    law_p_contact_kpa: Real | None = Field(None, description="contact pressure of the fitted law")


class ContactProvenance(StrictModel):
    """The contact step of a characterisation: the targets, what the rig read at each, and
    the simulated cell of the written profile at the same targets (the check)."""

    scene: str = Field(max_length=40, description="the scene kind the targets are")
    target: str = Field(max_length=40, description="the scene field that sizes them")
    unit: str = Field("", max_length=20)
    p0_kpa: Real
    cycles_per_target: Integer = Field(ge=1, le=10_000)
    free: ContactReading
    readings: list[ContactReading] = Field(min_length=1, max_length=100)
    chi2: Real | None = Field(None, ge=0, description="the contact fit's chi-square (None: as many readings as "
                              "parameters)")
    dof: Integer = Field(ge=0)
    simulated: list[ContactReading] = Field(default_factory=list, max_length=101, description="the same cycles on "
                                            "the simulated cell of the written profile (virtual time): free, then "
                                            "each target")
    check: list[str] = Field(default_factory=list, max_length=200, description="the simulated cell against the "
                             "rig, per reading, in words")


class Provenance(StrictModel):
    """Where a characterised profile's numbers came from (``fluidsense characterise``): the
    rig, the date, the config, the cycles, the fit's residual; which fields were fitted
    (with their 95 % intervals) and which were kept from the starting profile, and why.
    A shipped profile has none: its numbers come from the paper (see its comments)."""

    tool: Literal["fluidsense characterise"] = "fluidsense characterise"
    date: str = Field(min_length=1, max_length=40, description="UTC, ISO 8601")
    rig: str = Field(max_length=400, description="the driver and where it reached the cell")
    config: str = Field(max_length=1000, description="the cell config the run was given")
    from_profile: str = Field(max_length=1000, description="the starting profile (its name and file)")
    levels_kpa: list[Real] = Field(min_length=1, max_length=100, description="the P0 levels swept (free air)")
    cycles_per_level: Integer = Field(ge=1, le=10_000)
    cycle_ids: list[Integer] = Field(default_factory=list, max_length=100_000)
    residual_kpa: Real = Field(ge=0, description="rms of the P-V fit's residual over the levels' means")
    pure_error_kpa: Real = Field(ge=0, description="pooled cycle-to-cycle sd of the free-air equilibrium")
    residual_ml: Real | None = Field(None, ge=0, description="pressure-flow circuit: rms of the V_eq fit's "
                                     "residual over the levels' means (residual_kpa is it carried to pressure "
                                     "through the law's slope); None for a tank circuit")
    pure_error_ml: Real | None = Field(None, ge=0, description="pressure-flow circuit: pooled cycle-to-cycle sd "
                                       "of V_eq about the law")
    fitted: list[FittedNumber] = Field(default_factory=list, max_length=100)
    measured: list[FittedNumber] = Field(default_factory=list, max_length=100, description="numbers the rig "
                                         "showed that no profile field holds (reported, not used)")
    kept: dict[str, str] = Field(default_factory=dict, description="field -> why the starting value was kept")
    notes: list[str] = Field(default_factory=list, max_length=100)
    contact: ContactProvenance | None = Field(None, description="the contact step (--targets): None when the "
                                              "contact law was kept from the starting profile")


class Profile(StrictModel):
    """One actuator or gripper: its hardware, its safe envelope and its cycle."""

    name: str = Field(min_length=1, max_length=80)
    description: str = ""
    circuit: Circuit = TankCircuit()
    actuator: Actuator = GripperActuator()
    sensor: Sensor = Sensor()
    tank_sensor: Sensor = Sensor(offset_kpa=0.0)
    flow_sensor: FlowSensor = FlowSensor()
    limits: Limits = Limits(max_kpa=90.0, min_kpa=-5.0)
    sequence: SequenceConfig = SequenceConfig()
    calibration: CalibrationPlan | None = None
    budget: PartsBudget = Field(default_factory=PartsBudget, description="the parts' error budget "
                                "(common/budget.py; figures and sources in simulator/parts.py)")
    provenance: Provenance | None = Field(
        None, description="a characterised profile: which numbers were measured on which rig, with their 95 % "
        "intervals, and which were kept from the starting profile (fluidsense characterise); None: a shipped "
        "profile, whose numbers come from the paper")

    @model_validator(mode="after")
    def _consistent(self) -> Profile:
        seq, circuit = self.sequence, self.circuit
        p0 = seq.p0_kpa
        if seq.method != "flow_control":
            lo, hi, margin = self.limits.min_kpa, self.limits.max_kpa, self.p0_margin_kpa
            if not lo <= p0 <= hi:
                raise FieldError("sequence.p0_kpa", f"{p0} is outside limits [{lo}, {hi}] kPa")
            if not lo + margin <= p0 <= hi - margin:
                raise FieldError("sequence.p0_kpa", f"{p0} is within {margin:.2f} kPa of limits [{lo}, {hi}] kPa: "
                                 "the readings around P0 would cross the limit and fault the cycle (sensor offset, "
                                 "noise and regulator repeatability); lower P0 or widen the limits")
        needs = {"tank": "tank", "pressure_flow": "regulated", "flow_control": "flow"}[seq.method]
        if circuit.kind != needs:
            raise ValueError(f"sequence.method {seq.method!r} needs circuit.kind {needs!r}, got {circuit.kind!r}")
        if seq.flow_window is not None and not circuit.flow_sensor:
            raise ValueError("sequence.flow_window needs a circuit with flow_sensor: true")
        if seq.isolate_actuator_at_s is not None and not getattr(circuit, "vent_valve", False):
            raise ValueError("sequence.isolate_actuator_at_s needs circuit.vent_valve: true")
        return self

    @property
    def p0_margin_kpa(self) -> float:
        """How far inside the limits P0 must stay. The supervisor compares every raw reading
        of every pressure channel with the limits; the tank sensor reads P0 for the whole
        charge (charge_s + isolate_s: 2e4 samples per cycle at 1 kHz with the defaults),
        and the actuator sensor gets there with the regulated methods. A reading is P0 +
        the regulator's error for this charge (sd ``regulator_repeatability_kpa``, once
        per cycle) + the sensor's offset + noise (sd ``noise_sd_kpa``, every sample) +
        up to one quantum. The margin takes 4 sd of the regulator (beyond it: 3e-5 of
        cycles) and 6 sd of the noise (2e4 samples x 1e-9 each: 2e-5 of cycles), plus the
        largest |offset| and quantum. With the default sensors that is about 1.1 kPa. On
        the simulated gripper at P0 = 63 kPa (offset 0 on the tank sensor) a limit 0.25 kPa
        above P0 faulted 26 of 40 cycles, 0.5 kPa 1 of 400, 0.75 kPa none of 400. Real
        regulators may overshoot a step: give their datasheet's repeatability (or more)
        in the circuit so the margin covers it."""
        sensors = [self.sensor, *([self.tank_sensor] if self.circuit.has_tank_sensor else [])]
        regulator_sd = getattr(self.circuit, "regulator_repeatability_kpa", 0.0)
        return (max(abs(s.offset_kpa) for s in sensors) + max(s.quantum_kpa for s in sensors)
                + 4.0 * regulator_sd + 6.0 * max(s.noise_sd_kpa for s in sensors))

    @property
    def session_rel_sd(self) -> float:
        """What a rig set up again adds to every reading, as a fraction of the feature: the
        budget's per-session parts on this method's drive (a regulated P0, or the flow
        controller's programme). A calibration carries it to its intervals."""
        flow = self.sequence.method == "flow_control"
        return self.budget.session_rel_sd(None if flow else self.sequence.p0_kpa, flow_driven=flow)

    @property
    def hardware(self) -> Hardware:
        return Hardware(circuit=self.circuit, actuator=self.actuator, sensor=self.sensor,
                        tank_sensor=self.tank_sensor, flow_sensor=self.flow_sensor, budget=self.budget)
