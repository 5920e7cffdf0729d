"""Settings of the Modbus driver (``driver: {kind: modbus}``)."""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

from fluidsense.common.models import FieldError, Host, Integer, Port, Real, StrictModel
from fluidsense.common.wiring import AnalogScale, Wiring
from pydantic import Field, ValidationInfo, field_validator, model_validator

from ..entry import BLOCK_SIZE
from ..reconnect import Reconnect
from ..sampler.config import SamplerOptions
from ..ur.box import BoxWatchdogConfig, UrArmConfig, check_controller_rate, check_watchdog_program
from ..ur.config import UrBoxEntry
from ..ur.dashboard import Robot

Register = Annotated[Integer, Field(ge=0, le=65535)]


class RegisterMap(StrictModel):
    """Where things are, as holding registers. The defaults are the UR control box's
    Modbus server (docs/architecture.md, decision 5); a generic Modbus I/O module sets its own and
    leaves out what it lacks (null)."""

    digital_outputs: Register = Field(1, description="read back: bit n is output n")
    set_mask: Register | None = Field(2, description="writing sets those output bits (null: read-modify-write)")
    clear_mask: Register | None = Field(3, description="writing clears those output bits")
    analog_inputs: tuple[Register, Register] = Field((4, 6), description="raw 0..65535 of analog input 0, 1")
    analog_input_domains: tuple[Register, Register] | None = Field(
        (5, 7), description="0 current, 1 voltage; checked against the wiring at set-up and at every poll")
    analog_outputs: tuple[Register, Register] = (16, 18)
    analog_output_domains: tuple[Register, Register] | None = (17, 19)

    @model_validator(mode="after")
    def _masks_together(self) -> RegisterMap:
        if (self.set_mask is None) != (self.clear_mask is None):
            raise ValueError("set_mask and clear_mask go together (both, or neither)")
        polled = (*self.analog_inputs, *(self.analog_input_domains or ()))
        if max(polled) - min(polled) >= 125:
            raise ValueError("analog_inputs and analog_input_domains must lie within 125 registers of each other: "
                             "one poll reads them all")
        return self


class ModbusDriverConfig(UrBoxEntry):
    """Valves, regulator and analog inputs through Modbus TCP (pymodbus): by default a UR
    control box's Modbus server. The analog inputs are polled at ``rate_hz`` in the
    sampler process; valves and regulator are written from the daemon. Modbus cannot move
    a UR arm: ``arm`` moves it through ur_rtde (as the paper used Modbus for I/O next to
    a motion library), ``arm: null`` has none; the arm's interface also reports its
    protective stop to the supervisor."""

    backend_module: ClassVar[str] = "fluidsense.drivers.modbus.backend"

    kind: Literal["modbus"] = "modbus"
    host: Host
    port: Port = 502
    device_id: Integer = Field(1, ge=0, le=255, description="Modbus unit / slave id")
    timeout_s: Real = Field(0.5, gt=0, le=10, description="one request's answer")
    controller: Literal["e-series", "cb3", "io-module"] = Field(
        "e-series", description="what serves the registers: a UR control box of that generation refreshes them at "
        "its control rate (500 Hz e-Series, 125 Hz CB3), and rate_hz may not exceed it; io-module: a Modbus I/O "
        "module that converts at least as fast as rate_hz (check its data sheet)")
    rate_hz: Real = Field(500.0, ge=1, le=5000, description="analog input polls per second (at most the "
                          "controller's rate)")
    block_size: Integer = Field(10, ge=1, le=10_000, description=BLOCK_SIZE)
    registers: RegisterMap = RegisterMap()
    wiring: Wiring
    analog: AnalogScale = AnalogScale()
    arm: UrArmConfig | None = UrArmConfig()
    sampler: SamplerOptions = SamplerOptions()
    reconnect: Reconnect = Reconnect()
    watchdog: BoxWatchdogConfig | None = Field(
        BoxWatchdogConfig(), description="the box vents by itself when the service stops (null: no box-side "
        "watchdog, e.g. a Modbus I/O module that cannot run one; docs/safety.md says what that leaves)")
    sim_control_port: Port | None = Field(
        None, description="simulated cells only (fluidsense simcell): its control port; absent on a real cell")

    @model_validator(mode="after")
    def _watchdog_program(self) -> ModbusDriverConfig:
        try:
            check_watchdog_program(self.watchdog, arm=self.arm is not None)
        except ValueError as exc:
            raise FieldError("watchdog.program", str(exc)) from exc
        return self

    @field_validator("rate_hz")
    @classmethod
    def _box_rate(cls, rate_hz: float, info: ValidationInfo) -> float:
        return check_controller_rate(rate_hz, info.data.get("controller", "e-series"), "its Modbus server")

    def where(self) -> str:
        arm = "" if self.arm is None else f", the robot's RTDE port 30004 at {self.arm.host or self.host}"
        return f"the Modbus server at {self.host}:{self.port}{arm}"

    def what_to_check(self) -> str:
        return (f"check that the box is on, that `ping {self.host}` answers, that its Modbus server is enabled "
                f"(PolyScope: Installation > Fieldbus > Modbus) on port {self.port}, and driver.host/port in the "
                "config")

    def robot(self) -> Robot | None:
        # controller names what serves the registers (maybe an I/O module), not the robot's generation
        return None if self.arm is None else Robot(self.arm.host or self.host)

    def _modbus_port(self) -> int:
        return self.port
