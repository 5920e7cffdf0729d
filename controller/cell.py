"""What tasks use besides cycles: the arm, and (simulated cells only) the scene.

Tasks never reach into the backend: they move the arm and, on a simulated cell, place
objects and read the ground truth through their port (controller/ports.py TaskPort), whose
members are these (``ctrl.arm``, ``ctrl.scene``). On a real cell ``SceneAccess.available``
is False and ``truth()`` is None: the operator places objects and nobody knows the truth.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from fluidsense.common.errors import FaultError, NotSupportedError
from fluidsense.drivers.backend import Backend

from .path import Faults, SampleTime


class ArmAccess:
    """Straight-line moves of the tool, refused while a fault is latched."""

    def __init__(self, backend: Backend, faults: Faults, clock: SampleTime) -> None:
        """``faults``: the safety latch (a move is refused while a fault is latched)."""
        self._backend, self._faults, self._clock = backend, faults, clock

    @property
    def available(self) -> bool:
        return self._backend.arm is not None

    @property
    def protective_stopped(self) -> bool:
        return self._backend.arm is not None and self._backend.arm.protective_stopped

    @property
    def tcp_pose(self) -> tuple[float, ...]:
        return self._arm().tcp_pose

    async def move_l(self, pose: Sequence[float], speed: float, acc: float) -> None:
        """Move in a straight line; returns on arrival (sample time)."""
        arm = self._arm()
        fault = self._faults.fault
        if fault is not None:
            raise FaultError(f"in FAULT ({fault.kind}); send reset")
        await arm.move_l(pose, speed, acc, self._clock.now)

    def _arm(self):
        if self._backend.arm is None:
            raise NotSupportedError(f"backend {self._backend.name!r} has no arm")
        return self._backend.arm


class SceneAccess:
    """Objects in front of the actuator, and what is really there (simulated cells)."""

    def __init__(self, backend: Backend, clock: SampleTime) -> None:
        self._backend, self._clock = backend, clock

    @property
    def available(self) -> bool:
        """A simulated cell lays out its own objects; on a real one the operator does."""
        return self._backend.scene is not None

    async def place(self, scene: Any) -> None:
        await self._scene("cannot place objects").set_scene(scene, self._clock.now)

    async def lay_out(self, world: Any) -> None:
        """Slots and objects for an arm to work in."""
        await self._scene("cannot lay out a work cell").set_world(world, self._clock.now)

    async def truth(self) -> dict[str, Any] | None:
        """What a simulated cell knows and a real one cannot (to score a run); None on a
        real cell."""
        return None if self._backend.scene is None else await self._backend.scene.read_truth()

    def _scene(self, what: str):
        if self._backend.scene is None:
            raise NotSupportedError(f"backend {self._backend.name!r} {what}")
        return self._backend.scene
