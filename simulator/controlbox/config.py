"""Settings of the emulated control box (validated; unknown fields are errors)."""

from __future__ import annotations

from typing import Annotated, Literal

from fluidsense.common.models import StrictModel
from fluidsense.common.wiring import CONTROLLER_HZ, AnalogScale
from pydantic import Field

Port = Annotated[int, Field(ge=1, le=65535)]


class ControlBoxConfig(StrictModel):
    """Where the emulator listens and what controller it claims to be."""

    host: str = "127.0.0.1"
    rtde_port: Port = 30004
    dashboard_port: Port = 29999
    script_port: Port = 30003
    modbus_port: Port = 502
    #: the generation sets the control rate: the controller cycle (program steps, RTDE
    #: outputs, at most this rate) and the I/O image's refresh (e-Series 500 Hz, CB3 125 Hz)
    controller: Literal["e-series", "cb3"] = "e-series"
    #: the I/O image's refresh when it is not the control rate (a Modbus I/O module that
    #: converts faster than the box it stands in for); None: the control rate
    io_refresh_hz: float | None = Field(None, gt=0, le=10_000)
    #: controller software version reported by RTDE ``v`` and the dashboard
    version: tuple[int, int, int, int] = (5, 11, 1, 108318)
    serial_number: str = Field("20235500123", pattern=r"^\d+$")
    robot_model: str = "UR5"
    #: dashboard ``is in remote control``; ur_rtde refuses to start a control script
    #: on PolyScope >= 5.6 when this is false
    remote_control: bool = True
    #: the dashboard refuses ``unlock protective stop`` this long after the stop (s)
    unlock_delay_s: float = Field(5.0, ge=0, le=60)
    analog: AnalogScale = AnalogScale()

    @property
    def control_hz(self) -> float:
        return CONTROLLER_HZ[self.controller]

    @property
    def io_hz(self) -> float:
        return self.io_refresh_hz or self.control_hz

    @property
    def polyscope_version(self) -> str:
        return "URSoftware " + ".".join(map(str, self.version)) + " (Dec 06 2021)"
