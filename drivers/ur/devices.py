"""Devices of a UR control box driven through the ur_rtde worker: valves on digital
outputs, the regulator on an analog output, the arm. None of them imports ur_rtde."""

from __future__ import annotations

import logging
import math

from fluidsense.common.errors import DriverError, SafetyError
from fluidsense.common.wiring import AnalogScale, RegulatorWiring, ValveWiring
from fluidsense.drivers.ur.box import BoxWatchdogConfig, UrArmConfig

from ..base import Arm, BoxWatchdog, Pose, Regulator, ValveBank
from .link import WorkerConnection
from .worker import SCRIPT_START_S

log = logging.getLogger(__name__)


class UrValves(ValveBank):
    reports_outputs = True

    def __init__(self, link: WorkerConnection, wiring: dict[str, ValveWiring], safe: dict[str, bool]):
        super().__init__("ur-valves", safe)
        self.link, self.wiring = link, wiring

    async def _set(self, valve: str, open: bool, t: float) -> None:
        w = self.wiring[valve]
        await self.link.call("digital_out", output=w.output, level=w.level(open))

    async def _read_positions(self) -> dict[str, bool]:
        # a status taken after the last write reached the box: the worker's next one may
        # predate it by up to one RTDE period
        status = await self.link.fresh_status()
        bits = int(status["digital_outputs"])
        return {name: bool(bits >> w.output & 1) == w.level(True) for name, w in self.wiring.items()}


class WorkerKick(BoxWatchdog):
    """Kicks ur_rtde's RTDE watchdog through the worker; the control script stops (and the
    box's run-state output actions vent) when the kicks stop (drivers/ur/watchdog.py)."""

    def __init__(self, link: WorkerConnection, cfg: BoxWatchdogConfig):
        super().__init__("ur-rtde-watchdog", cfg.timeout_s)
        self.link = link

    async def _kick(self) -> None:
        self.link.notify("kick")

    async def _ensure_running(self) -> None:
        await self.link.call("ensure_program", timeout_s=SCRIPT_START_S + 2.0)


class UrRegulator(Regulator):
    def __init__(self, link: WorkerConnection, wiring: RegulatorWiring, scale: AnalogScale):
        super().__init__("ur-regulator")
        self.link, self.wiring, self.scale = link, wiring, scale

    async def _set_setpoint(self, pressure_pa: float, t: float) -> None:
        w = self.wiring
        ratio = self.scale.ratio(w.to_signal(pressure_pa), w.input)
        await self.link.call("analog_out", channel=w.analog_output, domain=w.input, ratio=ratio)


def move_timeout_s(start: Pose, target: Pose, speed: float, acc: float) -> float:
    """Generous bound on a straight move's duration (slowed by the speed slider, which
    the operator may turn down to 10 %)."""
    nominal = math.dist(start[:3], target[:3]) / speed + 2 * speed / acc
    return 10.0 * nominal + 5.0


class UrArm(Arm):
    """The arm through ur_rtde's control script. ``move_l`` returns on arrival; a move that
    ends elsewhere (stopped, protective stop, script ended) raises."""

    def __init__(self, link: WorkerConnection, cfg: UrArmConfig):
        super().__init__("ur-arm", max_speed=cfg.max_speed_m_s, max_acc=cfg.max_acc_m_s2)
        self.link = link

    @property
    def tcp_pose(self) -> Pose:
        status = self.link.status
        if status is None:
            raise DriverError("no pose from the robot yet")
        return tuple(status["pose"])  # type: ignore[return-value]

    @property
    def protective_stopped(self) -> bool:
        status = self.link.status
        return bool(status and status["protective_stop"])

    async def _move_l(self, pose: Pose, speed: float, acc: float, t: float) -> None:
        start = self.tcp_pose
        # the worker may first have to upload ur_rtde's script again (after a protective stop)
        reply = await self.link.call("move_l", timeout_s=SCRIPT_START_S + 2.0, pose=list(pose), speed=speed, acc=acc)
        move_id = reply["move_id"]
        status = await self.link.wait_status(
            lambda s: (s["move_id"] == move_id and s["move_result"] is not None) or s["protective_stop"],
            move_timeout_s(start, pose, speed, acc))
        if status["protective_stop"]:
            raise SafetyError("the arm protective-stopped during the move")
        if status["move_result"] != "arrived":
            raise DriverError(f"the move ended before its target: {status['move_result']}")

    async def _stop_motion(self, t: float) -> None:
        await self.link.call("stop_l", acc=self.max_acc)
