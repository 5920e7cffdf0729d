"""The simulated arm as a device: straight-line tool moves in sample time.

A move takes the time it takes in sample time (the cell's arm model), so in virtual time
a task's motion costs nothing but its samples.
"""

from __future__ import annotations

from fluidsense.common.errors import DriverError
from fluidsense.simulator.cell import SimulatedCell

from ..base import Arm, Pose


class SimArm(Arm):
    def __init__(self, cell: SimulatedCell):
        super().__init__("sim-arm", max_speed=1.0, max_acc=3.0)
        self.cell = cell

    @property
    def tcp_pose(self) -> Pose:
        return self.cell.arm.pose_at(self.cell.t_last)

    @property
    def protective_stopped(self) -> bool:
        return self.cell.arm.stopped

    async def _move_l(self, pose: Pose, speed: float, acc: float, t: float) -> None:
        if self.clock is None:
            raise DriverError("the simulated arm moves in sample time: attach the controller's clock first")
        move = self.cell.arm.start(pose, speed, acc, t)
        self.cell.on_arm_move(t)
        await self.clock.wait_until(t + move.duration)
        if not self.cell.arm.arrive(move):
            raise DriverError("the move was stopped before it arrived")

    async def _stop_motion(self, t: float) -> None:
        self.cell.arm.stop(t)
