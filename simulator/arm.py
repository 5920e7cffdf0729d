"""The simulated arm's motion: straight-line tool moves that take their time in sample
time (a trapezoidal line, the emulated control box's ``LineMove``)."""

from __future__ import annotations

import logging

from .controlbox.motion import LineMove, Pose

log = logging.getLogger(__name__)

HOME: Pose = (0.3, -0.2, 0.4, 0.0, 3.1416, 0.0)


class ArmModel:
    def __init__(self, home: Pose = HOME):
        self._pose: Pose = tuple(home)  # type: ignore[assignment]
        self._move: LineMove | None = None
        self._move_t0 = 0.0
        self.stopped = False  # protective stop (fault injection)

    def pose_at(self, t: float) -> Pose:
        if self._move is None:
            return self._pose
        tau = t - self._move_t0
        return tuple(self._move.pose(min(max(tau, 0.0), self._move.duration)))  # type: ignore[return-value]

    def start(self, pose: Pose, speed: float, acc: float, t: float) -> LineMove:
        """A move from wherever the tool is at ``t``; it arrives ``move.duration`` later."""
        move = LineMove(self.pose_at(t), pose, speed, acc)
        self._move, self._move_t0 = move, t
        return move

    def arrive(self, move: LineMove) -> bool:
        """``move`` has had its time: False when it was stopped (or replaced) meanwhile."""
        if self._move is not move:
            return False
        self._pose, self._move = tuple(move.pose(move.duration)), None  # type: ignore[assignment]
        return True

    def stop(self, t: float) -> None:
        if self._move is not None:
            self._pose = self.pose_at(t)
            self._move = None
            log.info("arm stopped at t=%.3f", t)
