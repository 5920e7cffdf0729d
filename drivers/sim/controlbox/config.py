"""Settings of the emulated control box (validated; unknown fields are errors)."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, model_validator

from ...models import StrictModel

Port = Annotated[int, Field(ge=1, le=65535)]


class AnalogScale(StrictModel):
    """How Modbus raw counts (0..65535) and RTDE ratios (0..1) map to signal values.

    UR does not document the raw count scale; the defaults map the full count range onto
    the analog I/O's electrical range (0-10 V, 4-20 mA). RTDE's analog output ratio uses
    the same ranges (ratio 0 -> 4 mA, ratio 1 -> 20 mA)."""

    voltage_v: tuple[float, float] = (0.0, 10.0)
    current_ma: tuple[float, float] = (4.0, 20.0)

    @model_validator(mode="after")
    def _ordered(self) -> AnalogScale:
        for name in ("voltage_v", "current_ma"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise ValueError(f"{name} must be [low, high] with low < high, got {[lo, hi]}")
        return self

    def span(self, domain: int) -> tuple[float, float]:
        """(low, high) in SI units (V or A) for an ``AnalogDomain`` value."""
        if domain == 1:
            return self.voltage_v
        lo, hi = self.current_ma
        return lo / 1e3, hi / 1e3


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
