"""Settings of the emulated control box (validated; unknown fields are errors)."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from common.models import StrictModel
from common.wiring import AnalogScale

Port = Annotated[int, Field(ge=1, le=65535)]


class ControlBoxConfig(StrictModel):
    """Where the emulator listens and what controller it claims to be."""

    host: str = "127.0.0.1"
    rtde_port: Port = 30004
    dashboard_port: Port = 29999
    script_port: Port = 30003
    modbus_port: Port = 502
    #: highest RTDE output frequency a client may ask for (e-Series: 500 Hz, CB3: 125 Hz)
    rtde_max_hz: float = Field(500.0, gt=0, le=500)
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
    def polyscope_version(self) -> str:
        return "URSoftware " + ".".join(map(str, self.version)) + " (Dec 06 2021)"
