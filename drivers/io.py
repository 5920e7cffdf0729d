"""How the production drivers reach a UR control box: where it is, how they reconnect,
the arm's limits and the box's own watchdog. The wiring itself (what is connected where)
is common/wiring.py: the emulated box reads it too."""

from __future__ import annotations

from fluidsense.common.models import Host, Integer, Port, Real, StrictModel
from fluidsense.common.wiring import CONTROLLER_HZ, Wiring  # noqa: F401 - the drivers' configs take them from here
from pydantic import Field

from .sampler.config import SamplerOptions  # noqa: F401 - drivers' configs take it from here

BLOCK_SIZE = ("samples per delivered block. The block period block_size / rate_hz must be at least 5 ms (the sample "
              "loop yields to commands and signals only between blocks) and at most supervision.no_data_s / 5 "
              "(else waiting for a block is a no_data fault); the cell config checks both")


def check_controller_rate(rate_hz: float, controller: str, path: str) -> float:
    """``rate_hz`` when the generation's ``path`` (what carries the samples) delivers it."""
    limit = CONTROLLER_HZ.get(controller)
    if limit is not None and rate_hz > limit:
        raise ValueError(f"{rate_hz:g} Hz: UR control-box analog inputs come through {path} at {limit:g} Hz at most on "
                         f"{controller} controllers (the box's control rate; a faster poll reads each value again "
                         "and stamps it as new); for 1 kHz use kind serial or nidaqmx (docs/drivers.md)")
    return rate_hz


class Reconnect(StrictModel):
    """After a lost link the source tries again, waiting ``first_s``, then twice as long
    each time up to ``max_s``. The cell stays in FAULT until an operator resets it."""

    first_s: Real = Field(0.5, gt=0, le=60)
    max_s: Real = Field(10.0, gt=0, le=600)
    connect_timeout_s: Real = Field(15.0, gt=0, le=120, description="time allowed to connect each time")


class UrArmConfig(StrictModel):
    """The arm, moved through ur_rtde's control interface (its script runs on the robot)."""

    host: Host | None = Field(None, description="the robot; default: the driver's host")
    max_speed_m_s: Real = Field(1.0, gt=0, le=3.0, description="moves faster than this are refused")
    max_acc_m_s2: Real = Field(3.0, gt=0, le=15.0)
    status_hz: Real = Field(50.0, ge=1, le=500, description="pose and safety state updates")
    upper_range_registers: bool = Field(
        False, description="ur_rtde on RTDE registers 24-47 (when another program uses 0-23)")


class BoxWatchdogConfig(StrictModel):
    """The control box vents the gripper by itself when the service's heartbeat stops
    (drivers/ur/watchdog.py, docs/safety.md): run-state output actions plus, with an arm,
    ur_rtde's RTDE watchdog on its control script, without one, fluidsense's watchdog
    program watching ``heartbeat_register``."""

    timeout_s: Real = Field(0.5, ge=0.05, le=10.0, description="no heartbeat for this long: the box vents")
    heartbeat_register: Integer = Field(200, ge=128, le=255, description="cells without an arm: the Modbus general "
                                    "purpose register the daemon increments and the box's program watches")
    script_port: Port = Field(30003, description="the box's URScript port (the watchdog is sent there at set-up)")
