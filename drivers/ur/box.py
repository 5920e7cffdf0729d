"""The UR control box as the ur and modbus drivers reach it: the arm's limits, the box's
own vent watchdog, the rate its generation serves, and ``ControlBox``, what both
drivers' entries tell the commands about the box (their shared base, ``UrBoxEntry``, is
in config.py). The wiring itself (what is connected where) is common/wiring.py: the
emulated box reads it too. Pydantic only: importing this imports neither ur_rtde nor
pymodbus."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from fluidsense.common.models import Host, Integer, Port, Real, StrictModel
from fluidsense.common.wiring import CONTROLLER_HZ, AnalogScale, Wiring
from pydantic import Field


def check_controller_rate(rate_hz: float, controller: str, path: str) -> float:
    """``rate_hz`` when the generation's ``path`` (what carries the samples) delivers it."""
    limit = CONTROLLER_HZ.get(controller)
    if limit is not None and rate_hz > limit:
        raise ValueError(f"{rate_hz:g} Hz: UR control-box analog inputs come through {path} at {limit:g} Hz at most on "
                         f"{controller} controllers (the box's control rate; a faster poll reads each value again "
                         "and stamps it as new); for 1 kHz use kind serial or nidaqmx (docs/drivers.md)")
    return rate_hz


def check_watchdog_program(watchdog: BoxWatchdogConfig | None, arm: bool) -> BoxWatchdogConfig | None:
    """With an arm, ur_rtde's control script is the box's program and its RTDE watchdog
    the vent: an integrator's program cannot run beside it."""
    if watchdog is not None and arm and watchdog.program == "integrator":
        raise ValueError("program: integrator is for cells without an arm (arm: null): with an arm ur_rtde's "
                         "control script is the box's program, and its RTDE watchdog vents")
    return watchdog


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
    program: Literal["fluidsense", "integrator"] = Field(
        "fluidsense", description="cells without an arm: fluidsense: the driver sends its watchdog program to the "
        "box at every connection (it becomes the box's one program); integrator: the box runs the integrator's "
        "own program, which carries the watchdog thread (`fluidsense watchdog --config` prints it): the daemon "
        "increments heartbeat_register and sends nothing to the box")


@dataclass(frozen=True)
class ControlBox:
    """The UR control box behind a cell config: what ``fluidsense watchdog`` installs on
    it and what ``fluidsense simcell`` emulates."""

    host: str
    controller: str  # e-series, cb3, or io-module (a Modbus I/O module serving the registers)
    rate_hz: float  # the driver's analog input rate
    wiring: Wiring
    analog: AnalogScale
    watchdog: BoxWatchdogConfig | None
    arm: bool  # an arm moved through ur_rtde (its control script carries the RTDE watchdog)
    modbus_port: int | None  # the driver's Modbus port; None: the driver does not use Modbus
    sim_control_port: int | None  # a simulated cell's control port; None on a real box
