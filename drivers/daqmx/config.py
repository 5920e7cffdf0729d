"""Settings of the NI-DAQmx driver (``driver: {kind: nidaqmx}``): an NI multifunction DAQ
(USB-6001/6002/6003, USB/PCIe-63xx, cDAQ modules) that samples the pressure sensors on
its own sample clock, docs/drivers.md."""

from __future__ import annotations

from typing import ClassVar, Literal

from fluidsense.common.models import Integer, Real, StrictModel
from fluidsense.common.wiring import (
    RegulatorWiring,
    Transfer,
    check_distinct,
    wiring_problems,
)
from pydantic import Field, model_validator

from ..entry import BLOCK_SIZE, DeadLinkVent, DriverEntry

Terminal = Literal["default", "rse", "nrse", "differential", "pseudo_differential"]


def _ordered(name: str, pair: tuple[float, float]) -> None:
    if not pair[0] < pair[1]:
        raise ValueError(f"{name} must be [low, high] with low < high, got {list(pair)}")


class DaqSensorWiring(StrictModel):
    """A pressure sensor on one analog input (``DEV/aiN``)."""

    ai: Integer = Field(ge=0, le=255, description="analog input number: ai0, ai1, ...")
    terminal: Terminal = Field("default", description="input configuration: rse (single-ended, referenced to AI "
                               "GND), nrse, differential (aiN with aiN+8 on an M/X-series board), pseudo_differential; "
                               "default: the device's own")
    input_range: tuple[Real, Real] | None = Field(
        None, description="the span to measure, V (or mA for a current loop); the device selects its smallest range "
        "that holds it. Default: a linear transmitter's signal, else 0 to the sensor's supply")
    transfer: Transfer

    @model_validator(mode="after")
    def _check(self) -> DaqSensorWiring:
        if self.input_range is not None:
            _ordered("input_range", self.input_range)
        return self

    def limits(self) -> tuple[float, float]:
        """(min, max) for the channel in V or A (DAQmx's units): ``input_range``, else a
        linear transmitter's signal span, else 0 to the sensor's supply."""
        scale = 1.0 if self.transfer.domain == "voltage" else 1e-3
        if self.input_range is not None:
            return self.input_range[0] * scale, self.input_range[1] * scale
        if self.transfer.kind == "linear":
            lo, hi = sorted(self.transfer.signal)
            return lo * scale, hi * scale
        return 0.0, self.transfer.supply_v


class DaqValveWiring(StrictModel):
    """A solenoid valve on one digital output line (``DEV/portP/lineL``), through a
    relay or a MOSFET driver (a DAQ's lines do not drive a coil)."""

    port: Integer = Field(0, ge=0, le=15)
    line: Integer = Field(ge=0, le=31)
    open_when_energised: bool = Field(True, description="false for a normally-open valve: energising it closes it")

    def level(self, open_: bool) -> bool:
        return open_ == self.open_when_energised


class DaqRegulatorWiring(RegulatorWiring):
    """A proportional regulator on an analog output (``DEV/aoN``)."""

    analog_output: Integer = Field(ge=0, le=31, description="analog output number: ao0, ao1, ...")


class DaqWiring(StrictModel):
    """What is connected to which terminal of the DAQ. Valve names are the profile
    circuit's, sensor names its channels (the same rules as a UR box's ``wiring``)."""

    valves: dict[str, DaqValveWiring] = Field(min_length=1)
    regulator: DaqRegulatorWiring | None = None
    sensors: dict[str, DaqSensorWiring] = Field(min_length=1)

    @model_validator(mode="after")
    def _distinct(self) -> DaqWiring:
        lines = [(v.port, v.line) for v in self.valves.values()]
        check_distinct(lines, [s.ai for s in self.sensors.values()], [f"port{p}/line{n}" for p, n in lines],
                       "digital line")
        return self

    def check_against(self, valves: list[str], channels: tuple[str, ...], regulated: bool) -> list[str]:
        """Problems with wiring this to a circuit with these valves and sensor channels."""
        return wiring_problems(self, valves, channels, regulated)


class DaqWatchdogConfig(StrictModel):
    """The DAQ's own watchdog timer: it sets the valve lines (and the regulator's output,
    where the device can) to their safe levels when the service stops resetting it."""

    enabled: bool = Field(True, description="false only for a device without a watchdog timer (set-up says so): its "
                          "lines then keep their last level when the PC or the daemon dies")
    timeout_s: Real = Field(0.5, ge=0.02, le=30, description="no reset for this long (s): the device sets the safe "
                            "levels by itself")


class NiDaqDriverConfig(DriverEntry):
    """An NI DAQ sampling on its own clock into a buffer the driver reads in blocks;
    valves on digital lines and the regulator on an analog output, set on demand."""

    backend_module: ClassVar[str] = "fluidsense.drivers.daqmx.backend"

    kind: Literal["nidaqmx"] = "nidaqmx"
    device: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_]+$",
                        description="the device's name in NI MAX or `nidaqmx` (Dev1, cDAQ1Mod1)")
    rate_hz: Real = Field(1000.0, ge=1, le=250_000, description="samples per second per channel on the device's "
                          "sample clock (the device's aggregate maximum is checked when the task starts)")
    block_size: Integer = Field(10, ge=1, le=10_000, description=BLOCK_SIZE)
    buffer_s: Real = Field(2.0, ge=0.1, le=60, description="the input buffer in seconds of samples: a loop that "
                           "falls this far behind overflows it, which is a driver fault (never silent loss)")
    read_timeout_s: Real = Field(0.5, gt=0, le=10, description="a block not complete within this (s) is a no_data "
                                 "fault; keep it below supervision.no_data_s")
    clock_source: str = Field("", max_length=128, pattern=r"^[A-Za-z0-9_/]*$",
                              description="the sample clock's terminal (/Dev1/PFI0 for an external clock); empty: "
                              "the device's onboard clock")
    do_read_back: bool = Field(True, description="read the valve lines' output state back (most devices can; set "
                               "false where reading an output task is not supported)")
    wiring: DaqWiring
    watchdog: DaqWatchdogConfig = DaqWatchdogConfig()

    @model_validator(mode="after")
    def _buffer(self) -> NiDaqDriverConfig:
        if self.buffer_s * self.rate_hz < 4 * self.block_size:
            raise ValueError(f"buffer_s {self.buffer_s:g} s holds {self.buffer_s * self.rate_hz:.0f} samples: at "
                             f"least four blocks ({4 * self.block_size}) so that one late read does not overflow it")
        return self

    def dead_link_vent(self) -> DeadLinkVent:
        if not self.watchdog.enabled:
            return DeadLinkVent("none", f"{self.device} has its watchdog timer off (watchdog.enabled: "
                                "false): its lines keep their last level when the PC or the daemon dies",
                                fix="a device with a watchdog timer, and driver.watchdog.enabled: true")
        return DeadLinkVent("device_watchdog", f"the DAQ's watchdog timer: the valve lines at their safe levels "
                            f"{self.watchdog.timeout_s:g} s after the last reset", self.watchdog.timeout_s)

    def physical(self, kind: str, n: int, port: int | None = None) -> str:
        """The physical channel's name: ``Dev1/ai0``, ``Dev1/port0/line3``, ``Dev1/ao0``."""
        if kind == "line":
            return f"{self.device}/port{port}/line{n}"
        return f"{self.device}/{kind}{n}"
