"""The simulated arm: straight-line tool moves in sample time.

A move is a trapezoidal straight line (the emulated control box's ``LineMove``); it
takes the time it takes in sample time, so in virtual time a task's motion costs
nothing but its samples.
"""

from __future__ import annotations

import logging

from ..base import Arm, Pose
from ..errors import DriverError
from .controlbox.motion import LineMove

log = logging.getLogger(__name__)


class SimArm(Arm):
    def __init__(self, cell, home: Pose = (0.3, -0.2, 0.4, 0.0, 3.1416, 0.0)):
        super().__init__("sim-arm", max_speed=1.0, max_acc=3.0)
        self.cell = cell
        self._pose: Pose = tuple(home)  # type: ignore[assignment]
        self._move: LineMove | None = None
        self._move_t0 = 0.0
        self.stopped = False  # protective stop (fault injection)
        cell.arm = self

    def pose_at(self, t: float) -> Pose:
        if self._move is None:
            return self._pose
        tau = t - self._move_t0
        return tuple(self._move.pose(min(max(tau, 0.0), self._move.duration)))  # type: ignore[return-value]

    @property
    def tcp_pose(self) -> Pose:
        return self.pose_at(self.cell.t_last)

    @property
    def protective_stopped(self) -> bool:
        return self.stopped

    async def _move_l(self, pose: Pose, speed: float, acc: float, t: float) -> None:
        if self.clock is None:
            raise DriverError("the simulated arm moves in sample time: attach the controller's clock first")
        start = self.pose_at(t)
        move = LineMove(start, pose, speed, acc)
        self._move, self._move_t0 = move, t
        self.cell.on_arm_move(t)
        await self.clock.wait_until(t + move.duration)
        if self._move is not move:
            raise DriverError("the move was stopped before it arrived")
        self._pose, self._move = tuple(pose), None  # type: ignore[assignment]

    async def _stop_motion(self, t: float) -> None:
        if self._move is not None:
            self._pose = self.pose_at(t)
            self._move = None
            log.info("arm stopped at t=%.3f", t)
