"""Settings of the serial streaming driver (``driver: {kind: serial}``): a microcontroller
running firmware/ on USB serial, docs/drivers.md."""

from __future__ import annotations

from typing import ClassVar, Literal

from fluidsense.common.models import Integer, Port, Real, StrictModel
from fluidsense.common.wiring import (
    AnalogScale,
    RegulatorWiring,
    Transfer,
    ValveWiring,
    check_distinct,
    wiring_problems,
)
from pydantic import Field, model_validator

from ..entry import BLOCK_SIZE, DeadLinkVent, DriverEntry
from ..reconnect import Reconnect

#: the devices' boards: ADC inputs, digital outputs, analog outputs (firmware/README.md)
MAX_ADC, MAX_OUTPUTS = 8, 8


class SerialValveWiring(ValveWiring):
    """A solenoid valve on one of the device's digital outputs (through a MOSFET driver)."""

    output: Integer = Field(ge=0, le=MAX_OUTPUTS - 1, description="the device's digital output 0-7 (AVR board: "
                            "0-5 = D2-D7, 6 = D8, 7 = D11)")


class SerialSensorWiring(StrictModel):
    """A pressure sensor with a voltage output on one of the device's analog inputs."""

    adc: Integer = Field(ge=0, le=MAX_ADC - 1, description="analog input 0-7 (A0-A7; an Uno has A0-A5)")
    transfer: Transfer

    @model_validator(mode="after")
    def _volts(self) -> SerialSensorWiring:
        if self.transfer.domain != "voltage":
            raise ValueError("the device's ADC reads volts: put a 4-20 mA transmitter across a shunt resistor "
                             "(250 ohm: 1-5 V) and describe it as kind linear, output voltage, signal [1, 5]")
        return self


class SerialWiring(StrictModel):
    """What is connected to which pin of the device. Valve names are the profile
    circuit's, sensor names its channels (the same rules as a UR box's ``wiring``)."""

    valves: dict[str, SerialValveWiring] = Field(min_length=1)
    regulator: RegulatorWiring | None = Field(
        None, description="a proportional regulator on analog output 0 or 1 (AVR board: PWM on D9 or D10, "
        "filtered and amplified to the regulator's input)")
    sensors: dict[str, SerialSensorWiring] = Field(min_length=1)

    @model_validator(mode="after")
    def _distinct(self) -> SerialWiring:
        check_distinct([v.output for v in self.valves.values()], [s.adc for s in self.sensors.values()])
        return self

    def check_against(self, valves: list[str], channels: tuple[str, ...], regulated: bool) -> list[str]:
        """Problems with wiring this to a circuit with these valves and sensor channels."""
        return wiring_problems(self, valves, channels, regulated)


class AdcConfig(StrictModel):
    """How the device's ADC counts map onto volts: V = (count + 0.5) * reference_v / 2**bits
    (the middle of the count's interval)."""

    bits: Integer = Field(10, ge=8, le=16, description="resolution of the counts (the ATmega328P's ADC: 10); "
                          "checked against the device at every connection")
    reference_v: Real = Field(5.0, gt=0, le=10, description="the ADC's full scale in V (AVcc on an Arduino, 4.7-5.1 V "
                              "from USB: measure it; ratiometric sensors on the same 5 V cancel it)")


class SerialWatchdog(StrictModel):
    """The device vents by itself when the service's heartbeat stops (the firmware's own
    watchdog; always armed while a session runs)."""

    timeout_s: Real = Field(0.5, ge=0.02, le=60, description="no heartbeat for this long (s): the device sets every "
                            "wired valve output to its safe level and the regulator's output to 0 kPa")


class SerialDriverConfig(DriverEntry):
    """A microcontroller streaming hardware-timed samples over USB serial (firmware/):
    sample time is the device's timer, valves and the regulator are set by acknowledged
    commands, the device vents by itself when the heartbeat stops."""

    backend_module: ClassVar[str] = "fluidsense.drivers.serial.backend"

    kind: Literal["serial"] = "serial"
    port: str = Field(min_length=1, max_length=4096, pattern=r"^[^\x00]+$",
                      description="the device: /dev/serial/by-id/usb-... (the same after a replug), /dev/ttyACM0, or "
                      "the pty link of python -m lab simserial")
    baudrate: Integer = Field(500_000, ge=1200, le=4_000_000, description="bit/s: the firmware's BAUD (500000 for the "
                              "AVR image; a pty ignores it)")
    rate_hz: Integer = Field(1000, ge=1, le=10_000, description="samples per second of the device's timer (the AVR "
                             "board takes divisors of 10000 up to 2000)")
    block_size: Integer = Field(10, ge=1, le=10_000, description=BLOCK_SIZE)
    wiring: SerialWiring
    adc: AdcConfig = AdcConfig()
    analog_out: AnalogScale = Field(AnalogScale(), description="what the analog outputs' 0..65535 span after the "
                                    "board's filter and amplifier (V or mA, by the regulator's input)")
    watchdog: SerialWatchdog = SerialWatchdog()
    ack_timeout_s: Real = Field(0.05, gt=0, le=5, description="a command not acknowledged within this (s) is sent "
                                "again")
    retries: Integer = Field(3, ge=0, le=20, description="times a command is sent again before it fails (a command "
                             "fault)")
    silence_s: Real = Field(0.2, gt=0, le=10, description="no valid frame for this long (s): the link is lost "
                            "(link_lost fault, then reconnection); keep it below supervision.no_data_s")
    damaged_limit: Integer = Field(20, ge=1, le=100_000, description="frames lost or damaged within one second "
                                   "beyond which the link is unusable (driver fault); fewer cost only their own "
                                   "samples, reported as missed")
    reader: Literal["thread", "loop"] = Field(
        "thread", description="thread: a reader thread hands whole blocks to the event loop; loop: the event loop "
        "reads the port itself (add_reader). docs/performance.md measures both")
    reconnect: Reconnect = Reconnect()
    sim_control_port: Port | None = Field(
        None, description="simulated devices only (python -m lab simserial): its control port on 127.0.0.1; absent for "
        "a real device")

    def dead_link_vent(self) -> DeadLinkVent:
        return DeadLinkVent("device_watchdog", f"the device's own watchdog (firmware): every wired valve output safe "
                            f"and the regulator at 0 kPa {self.watchdog.timeout_s:g} s after the last heartbeat",
                            self.watchdog.timeout_s, self.reconnect.max_s)

    def emulator_hint(self) -> str | None:
        if self.sim_control_port is None:
            return None
        return ("this config is for the emulated serial device (it names sim_control_port): start it first, "
                "`python -m lab simserial --config` with this same file (in a checkout); for a real board set "
                "driver.port to it and delete sim_control_port")
