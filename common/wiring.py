"""How the pneumatics are wired to a controller's I/O: valves on digital outputs, the
regulator on an analog output, pressure sensors on analog inputs.

Shared by the production drivers that reach the cell through a UR control box (``ur``,
``modbus``) and by the emulated box (``fluidsense simcell``): one wiring section
describes both ends, so the emulator and the driver cannot disagree about which bit
is which valve.

Every transfer function here is affine, so each reduces to ``signal = gain * p + offset``
(SI: Pa gauge in, V or A out). The sampler-side pollers only ever see that pair and
stay free of pydantic.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field, model_validator

from .models import Integer, Real, StrictModel
from .units import KPA

RAW_MAX = 65535  # UR Modbus analog registers are unsigned 16-bit counts
#: the control rate per UR controller generation: the box refreshes its I/O (RTDE outputs and
#: the Modbus server's registers) no faster, so a faster poll reads each value again
CONTROLLER_HZ = {"e-series": 500.0, "cb3": 125.0}
Domain = Literal["voltage", "current"]


def _ordered(name: str, pair: tuple[float, float]) -> None:
    lo, hi = pair
    if not lo < hi:
        raise ValueError(f"{name} must be [low, high] with low < high, got {list(pair)}")


class AnalogScale(StrictModel):
    """How raw counts (Modbus, 0..65535) and RTDE ratios (0..1) map onto the analog I/O's
    electrical range. UR does not document the raw count scale; the defaults map the full
    count range onto 0-10 V and 4-20 mA (check one channel against a multimeter on a real
    box: docs/drivers.md)."""

    voltage_v: tuple[Real, Real] = (0.0, 10.0)
    current_ma: tuple[Real, Real] = (4.0, 20.0)

    @model_validator(mode="after")
    def _check(self) -> AnalogScale:
        _ordered("voltage_v", self.voltage_v)
        _ordered("current_ma", self.current_ma)
        return self

    def span(self, domain: int | str) -> tuple[float, float]:
        """(low, high) in SI units (V or A); ``domain`` is 1 / "voltage" or 0 / "current"
        (UR's AnalogDomain numbering)."""
        if domain in (1, "voltage"):
            return self.voltage_v
        lo, hi = self.current_ma
        return lo / 1e3, hi / 1e3

    def ratio(self, signal: float, domain: int | str) -> float:
        """Signal (V or A) -> fraction of the range, clipped to [0, 1]."""
        lo, hi = self.span(domain)
        return min(1.0, max(0.0, (signal - lo) / (hi - lo)))

    def raw_affine(self, domain: int | str) -> tuple[float, float]:
        """(gain, offset) with signal = gain * raw + offset."""
        lo, hi = self.span(domain)
        return (hi - lo) / RAW_MAX, lo


# ------------------------------------------------------------------ sensor transfer
class _Transfer(StrictModel):
    @property
    def domain(self) -> Domain:
        return "voltage"

    def affine(self) -> tuple[float, float]:
        """(gain, offset): signal (V or A) = gain * p (Pa gauge) + offset."""
        raise NotImplementedError

    def to_signal(self, p_pa: float) -> float:
        gain, offset = self.affine()
        return gain * p_pa + offset

    def to_pa(self, signal: float) -> float:
        gain, offset = self.affine()
        return (signal - offset) / gain


class Ratiometric(_Transfer):
    """Ratiometric sensor: the output spans ``output_fraction`` of the supply over
    ``range_kpa`` (Honeywell SSC/ABP: 10-90 % of 5 V)."""

    kind: Literal["ratiometric"] = "ratiometric"
    supply_v: Real = Field(5.0, gt=0, le=30)
    output_fraction: tuple[Real, Real] = (0.1, 0.9)
    range_kpa: tuple[Real, Real]

    @model_validator(mode="after")
    def _check(self) -> Ratiometric:
        _ordered("range_kpa", self.range_kpa)
        _ordered("output_fraction", self.output_fraction)
        if not (0 <= self.output_fraction[0] and self.output_fraction[1] <= 1):
            raise ValueError("output_fraction must lie within [0, 1]")
        return self

    def affine(self) -> tuple[float, float]:
        (f0, f1), (p0, p1) = self.output_fraction, self.range_kpa
        gain = self.supply_v * (f1 - f0) / ((p1 - p0) * KPA)
        return gain, self.supply_v * f0 - gain * p0 * KPA


class Mpx(_Transfer):
    """NXP MPX-style sensor: ``Vout = Vs * (a * P + b)``, P in kPa (MPX4250:
    a = 0.004, b = 0.04 on absolute pressure; give b for gauge here)."""

    kind: Literal["mpx"] = "mpx"
    supply_v: Real = Field(5.0, gt=0, le=30)
    a_per_kpa: Real = Field(gt=0)
    b: Real

    def affine(self) -> tuple[float, float]:
        return self.supply_v * self.a_per_kpa / KPA, self.supply_v * self.b


class Linear(_Transfer):
    """Transmitter with a linear output: ``signal`` (V, or mA for current loops) over
    ``range_kpa``."""

    kind: Literal["linear"] = "linear"
    output: Domain = "current"
    signal: tuple[Real, Real] = Field((4.0, 20.0), description="output at the range's ends (V or mA)")
    range_kpa: tuple[Real, Real]

    @model_validator(mode="after")
    def _check(self) -> Linear:
        _ordered("range_kpa", self.range_kpa)
        if self.signal[0] == self.signal[1]:
            raise ValueError("signal ends must differ")
        return self

    @property
    def domain(self) -> Domain:
        return self.output

    def affine(self) -> tuple[float, float]:
        scale = 1.0 if self.output == "voltage" else 1e-3
        (s0, s1), (p0, p1) = self.signal, self.range_kpa
        gain = (s1 - s0) * scale / ((p1 - p0) * KPA)
        return gain, s0 * scale - gain * p0 * KPA


Transfer = Annotated[Ratiometric | Mpx | Linear, Field(discriminator="kind")]


# ------------------------------------------------------------------ wiring
AnalogChannel = Annotated[Integer, Field(ge=0, le=1, description="standard analog I/O 0 or 1")]


class SensorWiring(StrictModel):
    analog_input: AnalogChannel
    transfer: Transfer


class ValveWiring(StrictModel):
    """A solenoid valve on a digital output (0-7 standard, 8-15 configurable)."""

    output: Integer = Field(ge=0, le=15)
    open_when_energised: bool = Field(
        True, description="false for a normally-open valve: energising it closes it")

    def level(self, open_: bool) -> bool:
        return open_ == self.open_when_energised


class RegulatorWiring(StrictModel):
    """A proportional pressure regulator (e.g. SMC ITV) driven by an analog output."""

    analog_output: AnalogChannel
    input: Domain = "voltage"
    signal: tuple[Real, Real] = Field((0.0, 10.0), description="command at the range's ends (V or mA)")
    range_kpa: tuple[Real, Real] = Field((0.0, 500.0), description="output pressure at those commands")

    @model_validator(mode="after")
    def _check(self) -> RegulatorWiring:
        _ordered("range_kpa", self.range_kpa)
        _ordered("signal", self.signal)
        return self

    def to_signal(self, p_pa: float) -> float:
        """Setpoint (Pa gauge) -> command (V or A), clipped to the signal range."""
        (s0, s1), (p0, p1) = self.signal, self.range_kpa
        frac = min(1.0, max(0.0, (p_pa / KPA - p0) / (p1 - p0)))
        return (s0 + frac * (s1 - s0)) * (1.0 if self.input == "voltage" else 1e-3)

    def to_pa(self, signal: float) -> float:
        """Command (V or A) -> the pressure the regulator sets."""
        (s0, s1), (p0, p1) = self.signal, self.range_kpa
        s = signal / (1.0 if self.input == "voltage" else 1e-3)
        frac = min(1.0, max(0.0, (s - s0) / (s1 - s0)))
        return (p0 + frac * (p1 - p0)) * KPA


def check_distinct(outputs: list, inputs: list, output_names: list[str] | None = None,
                   output_kind: str = "digital output") -> None:
    """Refuse (ValueError) two valves on one output or two sensors on one input."""
    if len(set(outputs)) != len(outputs):
        raise ValueError(f"two valves on one {output_kind}: {output_names or outputs}")
    if len(set(inputs)) != len(inputs):
        raise ValueError(f"two sensors on one analog input: {inputs}")


def wiring_problems(wiring: Any, valves: list[str], channels: tuple[str, ...], regulated: bool,
                    inputs_hint: str = "") -> list[str]:
    """Problems with wiring (any driver's: ``valves``, ``sensors``, ``regulator``) to a
    circuit with these valves and sensor channels."""
    problems = []
    if missing := [v for v in valves if v not in wiring.valves]:
        problems.append(f"valves {missing} of the profile's circuit are not wired (wired: {sorted(wiring.valves)})")
    if extra := [v for v in wiring.valves if v not in valves]:
        problems.append(f"valves {extra} are not in the profile's circuit (it has {valves})")
    if unwired := [c for c in channels if c not in wiring.sensors]:
        problems.append(f"channels {unwired} have no analog input{inputs_hint}")
    if regulated and wiring.regulator is None:
        problems.append("the profile's circuit has a regulator: wire it to an analog output")
    return problems


class Wiring(StrictModel):
    """What is connected where. Valve names are the profile circuit's (``supply``,
    ``actuate``, ``vent``); sensor names are its channels (``p_act``, ``p_tank``)."""

    valves: dict[str, ValveWiring] = Field(min_length=1)
    regulator: RegulatorWiring | None = None
    sensors: dict[str, SensorWiring] = Field(min_length=1)

    @model_validator(mode="after")
    def _distinct(self) -> Wiring:
        check_distinct([v.output for v in self.valves.values()], [s.analog_input for s in self.sensors.values()])
        return self

    def check_against(self, valves: list[str], channels: tuple[str, ...], regulated: bool) -> list[str]:
        """Problems with wiring this to a circuit with these valves and sensor channels."""
        return wiring_problems(self, valves, channels, regulated, " (a UR box has two: 0 and 1)")

