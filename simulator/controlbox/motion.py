"""Cartesian TCP motion for the emulated arm: straight lines with a trapezoidal speed
profile, velocity ramps (speedl) and decelerations (stopl).

A pose is UR's ``[x, y, z, rx, ry, rz]``: metres and a rotation vector in radians, in
the base frame. A motion is a *segment*: a pure function of its own time ``tau`` (s since
it started), so the model only keeps the active segment and how far into it it is. That
makes speed scaling (the speed slider) a matter of advancing ``tau`` more slowly, exactly
as UR's time scaling does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

Pose = tuple[float, float, float, float, float, float]

#: below this a translation or rotation counts as zero (m, rad)
EPS = 1e-9


def as_pose(values) -> Pose:
    """Six finite floats, or ValueError."""
    pose = tuple(float(v) for v in values)
    if len(pose) != 6 or not all(math.isfinite(v) for v in pose):
        raise ValueError(f"a pose is 6 finite numbers [x, y, z, rx, ry, rz], got {list(values)!r}")
    return pose  # type: ignore[return-value]


@dataclass(frozen=True)
class Trapezoid:
    """Distance travelled along a path of ``length`` with speed limit ``v`` and
    acceleration ``a``: accelerate, cruise, decelerate (a triangle when the path is too
    short to reach ``v``)."""

    length: float
    v: float
    a: float

    def __post_init__(self) -> None:
        if not (self.length >= 0 and self.v > 0 and self.a > 0):
            raise ValueError(f"trapezoid needs length >= 0, v > 0, a > 0, got {self}")

    @property
    def t_acc(self) -> float:
        return min(self.v / self.a, math.sqrt(self.length / self.a))

    @property
    def v_peak(self) -> float:
        return self.a * self.t_acc

    @property
    def t_cruise(self) -> float:
        if self.v_peak <= 0:
            return 0.0
        return max(0.0, (self.length - self.a * self.t_acc ** 2) / self.v_peak)

    @property
    def duration(self) -> float:
        return 2 * self.t_acc + self.t_cruise

    def distance(self, tau: float) -> float:
        t_acc, t_cruise, a, vp = self.t_acc, self.t_cruise, self.a, self.v_peak
        if tau <= 0:
            return 0.0
        if tau < t_acc:
            return 0.5 * a * tau ** 2
        if tau < t_acc + t_cruise:
            return 0.5 * a * t_acc ** 2 + vp * (tau - t_acc)
        if tau < self.duration:
            rest = self.duration - tau
            return self.length - 0.5 * a * rest ** 2
        return self.length

    def speed(self, tau: float) -> float:
        t_acc, t_cruise = self.t_acc, self.t_cruise
        if tau <= 0 or tau >= self.duration:
            return 0.0
        if tau < t_acc:
            return self.a * tau
        if tau < t_acc + t_cruise:
            return self.v_peak
        return self.a * (self.duration - tau)


class Segment:
    """One motion; ``pose(tau)`` and ``velocity(tau)`` for ``tau`` >= 0."""

    #: seconds of segment time after which the arm is still; inf for speedl
    duration: float

    def pose(self, tau: float) -> Pose:  # pragma: no cover - abstract
        raise NotImplementedError

    def velocity(self, tau: float) -> Pose:  # pragma: no cover - abstract
        raise NotImplementedError

    def target(self) -> Pose | None:
        """Where the segment ends, if it ends."""
        return None


class LineMove(Segment):
    """moveL: the TCP goes along the straight line from ``start`` to ``end`` while the
    orientation turns about one fixed axis (slerp). The speed limit applies to the
    translation; a pure rotation uses ``speed`` in rad/s and ``acc`` in rad/s^2."""

    def __init__(self, start: Pose, end: Pose, speed: float, acc: float):
        self.start, self.end = start, end
        self._p0 = np.array(start[:3])
        delta = np.array(end[:3]) - self._p0
        self._r0 = Rotation.from_rotvec(start[3:])
        self._turn = (Rotation.from_rotvec(end[3:]) * self._r0.inv()).as_rotvec()
        distance = float(np.linalg.norm(delta))
        angle = float(np.linalg.norm(self._turn))
        # the profile runs along whichever part is not zero; fractions of it drive both
        self._length = distance if distance > EPS else angle
        self._delta = delta
        self._rotates = angle > EPS
        self.profile = Trapezoid(self._length, speed, acc)
        self.duration = self.profile.duration

    def _fraction(self, tau: float) -> float:
        if self._length <= EPS:
            return 1.0
        return self.profile.distance(tau) / self._length

    def pose(self, tau: float) -> Pose:
        if tau >= self.duration:
            return self.end
        f = self._fraction(tau)
        xyz = self._p0 + f * self._delta
        rot = (Rotation.from_rotvec(f * self._turn) * self._r0).as_rotvec() if self._rotates else self.start[3:]
        return (*map(float, xyz), *map(float, rot))  # type: ignore[return-value]

    def velocity(self, tau: float) -> Pose:
        if self._length <= EPS:
            return (0.0,) * 6  # type: ignore[return-value]
        rate = self.profile.speed(tau) / self._length  # fraction per second
        lin = rate * self._delta
        ang = rate * self._turn
        return (*map(float, lin), *map(float, ang))  # type: ignore[return-value]

    def target(self) -> Pose:
        return self.end


class Ramp(Segment):
    """speedl / stopl: the TCP velocity goes linearly from ``v0`` to ``v1`` with
    acceleration ``acc`` (on the translational part, or on the rotational part when
    there is no translation), then stays at ``v1``. With ``v1`` zero it is a stop and
    ends when the arm is still; otherwise it never ends (speedl runs until stopped)."""

    def __init__(self, start: Pose, v0, v1, acc: float):
        if not acc > 0:
            raise ValueError(f"acceleration must be > 0, got {acc}")
        self.start = start
        self._p0 = np.array(start[:3])
        self._r0 = Rotation.from_rotvec(start[3:])
        self.v0 = np.array(v0, dtype=float)
        self.v1 = np.array(v1, dtype=float)
        dv = self.v1 - self.v0
        change = float(np.linalg.norm(dv[:3])) or float(np.linalg.norm(dv[3:]))
        self.t_ramp = change / acc
        still = not np.any(self.v1)
        self.duration = self.t_ramp if still else math.inf

    def _integral(self, tau: float) -> np.ndarray:
        """Displacement (translation and rotation vector) after ``tau`` seconds."""
        if self.t_ramp <= 0:
            return self.v1 * tau
        t = min(tau, self.t_ramp)
        ramp = self.v0 * t + (self.v1 - self.v0) * t * t / (2 * self.t_ramp)
        return ramp + self.v1 * max(0.0, tau - self.t_ramp)

    def pose(self, tau: float) -> Pose:
        d = self._integral(min(tau, self.duration))
        xyz = self._p0 + d[:3]
        # the rotation accumulates about the velocity's axis (exact when it does not turn)
        rot = (Rotation.from_rotvec(d[3:]) * self._r0).as_rotvec() if np.any(d[3:]) else self.start[3:]
        return (*map(float, xyz), *map(float, rot))  # type: ignore[return-value]

    def velocity(self, tau: float) -> Pose:
        if self.t_ramp <= 0 or tau >= self.t_ramp:
            v = self.v1
        else:
            v = self.v0 + (self.v1 - self.v0) * (tau / self.t_ramp)
        return tuple(float(x) for x in v)  # type: ignore[return-value]

    def target(self) -> Pose | None:
        return self.pose(self.duration) if math.isfinite(self.duration) else None
