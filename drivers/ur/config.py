"""Settings of the ur-rtde driver (``driver: {kind: ur}``), and ``UrBoxEntry``, what its
entry shares with the modbus driver's (a UR control box). Pydantic only: importing this
does not import ur_rtde."""

from __future__ import annotations

from typing import ClassVar, Literal

from fluidsense.common.models import Host, Integer, Port, Real
from fluidsense.common.wiring import CONTROLLER_HZ, AnalogScale, Wiring
from pydantic import Field, ValidationInfo, field_validator

from ..entry import BLOCK_SIZE, DeadLinkVent, DriverEntry
from ..reconnect import Reconnect
from ..sampler.config import SamplerOptions
from .box import BoxWatchdogConfig, ControlBox, UrArmConfig, check_controller_rate, check_watchdog_program
from .dashboard import Robot

#: highest RTDE output rate per controller generation (UR's RTDE guide): the control rate
RTDE_MAX_HZ = CONTROLLER_HZ


class UrBoxEntry(DriverEntry):
    """What the ur and modbus drivers' entries share: a UR control box at ``host``, wired
    as ``wiring`` says, with an optional ``sim_control_port`` when it is emulated. Methods
    only (the drivers' own fields keep their order)."""

    def _modbus_port(self) -> int | None:
        return None

    def control_box(self) -> ControlBox:
        return ControlBox(host=self.host, controller=self.controller, rate_hz=self.rate_hz, wiring=self.wiring,
                          analog=self.analog, watchdog=self.watchdog, arm=self.arm is not None,
                          modbus_port=self._modbus_port(), sim_control_port=self.sim_control_port)

    def dead_link_vent(self) -> DeadLinkVent:
        dog, arm, backoff = self.watchdog, self.arm is not None, self.reconnect.max_s
        if dog is None:
            if arm:
                fix = ("set driver.watchdog (delete `watchdog: null`): ur_rtde's control script, the box's program, "
                       "then runs under its RTDE watchdog and the run-state actions vent when it stops")
            else:
                fix = ("put the watchdog thread into the box's program (`fluidsense watchdog --config` prints it) and "
                       "set driver.watchdog: {program: integrator}, so that the daemon beats its register; or delete "
                       "`watchdog: null` and let fluidsense's own watchdog program be the box's program")
            return DeadLinkVent("none", "driver.watchdog is null: the control box keeps its outputs as last set",
                                reconnect_max_s=backoff, fix=fix)
        if arm:
            what = (f"the control box: ur_rtde's control script runs under its RTDE watchdog ({dog.timeout_s:g} s), "
                    "and the run-state actions set the valve outputs safe when it stops")
        elif dog.program == "integrator":
            what = (f"the control box: the watchdog thread in the integrator's program vents {dog.timeout_s:g} s "
                    f"after the heartbeat register {dog.heartbeat_register} stops (the integrator installs it: "
                    "fluidsense cannot confirm that it runs)")
        else:
            what = (f"the control box: fluidsense's watchdog program vents {dog.timeout_s:g} s after the heartbeat "
                    f"register {dog.heartbeat_register} stops")
        return DeadLinkVent("box_watchdog", what, dog.timeout_s, backoff)

    def emulator_hint(self) -> str | None:
        if self.sim_control_port is None:
            return None
        return ("this config is for the emulated control box (it names sim_control_port): start it first, "
                "`fluidsense simcell --config` with this same file; for a real box set driver.host to it and "
                "delete sim_control_port")

    def needs_operator(self) -> bool:
        # an emulated box's control port lays the scene out; a real box has nobody else
        return self.sim_control_port is None


class UrDriverConfig(UrBoxEntry):
    """A UR control box reached with ur_rtde: valves on its digital outputs, the
    regulator on an analog output (RTDE IO interface), pressure sensors on its analog
    inputs (RTDE receive, polled in the sampler process), the arm through the RTDE
    control interface."""

    backend_module: ClassVar[str] = "fluidsense.drivers.ur.backend"

    kind: Literal["ur"] = "ur"
    host: Host
    controller: Literal["e-series", "cb3"] = "e-series"
    rate_hz: Real = Field(500.0, ge=1, description="analog input sample rate (RTDE: 500 Hz e-Series, 125 Hz CB3)")
    block_size: Integer = Field(5, ge=1, le=10_000, description=BLOCK_SIZE)
    wiring: Wiring
    rtde_timeout_s: Real = Field(
        0.5, gt=0, le=10, description="RTDE data that stays the same for this long means the robot stopped "
        "sending (a lost link); a shorter pause is late packets, their slots missed. On a busy PC (or a busy "
        "emulated box) packets come tens of ms late; the sampler's link_timeout_s then ends the link")
    analog: AnalogScale = AnalogScale()
    arm: UrArmConfig = UrArmConfig()
    sampler: SamplerOptions = SamplerOptions()
    reconnect: Reconnect = Reconnect()
    watchdog: BoxWatchdogConfig | None = Field(
        BoxWatchdogConfig(), description="the box vents by itself when the service stops (null: no box-side "
        "watchdog, e.g. a Modbus I/O module that cannot run one; docs/safety.md says what that leaves)")
    sim_control_port: Port | None = Field(
        None, description="simulated cells only (fluidsense simcell): its control port, through which "
        "tasks lay out objects and score themselves; absent on a real robot")

    @field_validator("watchdog")
    @classmethod
    def _rtde_watchdog(cls, watchdog: BoxWatchdogConfig | None) -> BoxWatchdogConfig | None:
        return check_watchdog_program(watchdog, arm=True)

    @field_validator("rate_hz")
    @classmethod
    def _rtde_rate(cls, rate_hz: float, info: ValidationInfo) -> float:
        return check_controller_rate(rate_hz, info.data.get("controller", "e-series"), "RTDE")

    def where(self) -> str:
        return f"the robot at {self.host} (RTDE port 30004)"

    def what_to_check(self) -> str:
        return (f"check that the robot is on and booted, that `ping {self.host}` answers, that nothing else "
                "holds its RTDE inputs, and driver.host in the config")

    def robot(self) -> Robot:
        return Robot(self.arm.host or self.host, generation=self.controller)
