"""What a task may ask of the controller: its port.

A task (tasks/: the closed-loop tasks, calibration and sensing, characterisation, the
surveys and sweeps) holds a ``TaskPort`` and nothing else of the controller, as a request
handler holds its own (requests/ports.py): what it can touch is what the port lists, one
level deep. ``Controller.task_port`` builds it from the controller (service.py); a test
may build one from a fake. A job that runs on a cell of its own making (the chart's
simulated cell, tasks/speed_accuracy.py) is handed an ``OpenCell`` (service.open_cell). tasks/ never imports service.py (pyproject.toml's contract).

The arm and the scene are the controller's ``ArmAccess`` and ``SceneAccess`` (cell.py),
handed on member by member: a task never reaches the backend.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable, Sequence
from contextlib import AbstractAsyncContextManager
from dataclasses import dataclass
from typing import Any, Protocol

from fluidsense.common.faults import Fault
from fluidsense.drivers.backend import Backend

from .config import CellConfig, Profile
from .cycles.analysis import CycleResult, Reference


class RunCycle(Protocol):
    """How ``TaskPort.run_cycle`` is called (service.Controller.run_cycle)."""

    def __call__(self, *, p0_kpa: float | None = None, label: str | None = None,
                 store_reference: bool = False) -> Awaitable[CycleResult]:
        """One cycle at ``p0_kpa`` (None: the profile's), to its end: its result."""
        ...


class StartCycle(Protocol):
    """How ``TaskPort.start_cycle`` is called (service.Controller.start_cycle)."""

    def __call__(self, *, p0_kpa: float | None = None, label: str | None = None, store_reference: bool = False,
                 hold: bool = False) -> Awaitable[asyncio.Future[CycleResult]]:
        """A cycle started: the future of its result (``hold``: it stays inflated)."""
        ...


@dataclass(frozen=True)
class TaskPort:
    """The controller as a task uses it: cycles, the free-air references, the latched
    fault, progress events, the arm, and (simulated cells) the scene."""

    profile: Profile
    """The profile the cell runs (its sequence: P0, windows; its name), as data: read only."""
    now: Callable[[], float]
    """Sample time (s): the newest sample's timestamp."""
    run_cycle: RunCycle
    """Run one cycle to its end ``(p0_kpa=, label=, store_reference=)`` and return its result."""
    start_cycle: StartCycle
    """Start a cycle ``(p0_kpa=, label=, store_reference=, hold=)``: the future of its result.
    ``hold``: the actuator stays inflated after its windows until ``release``."""
    measured: Callable[[], Awaitable[CycleResult]]
    """The running (held) cycle's features, once its last measurement window has closed."""
    release: Callable[[], Awaitable[CycleResult]]
    """End a held cycle: vent, and return its final result."""
    wait_after_open: Callable[[float], Awaitable[None]]
    """Wait until this many seconds (sample time) after the running cycle's valve opened."""
    reference: Callable[[float], Reference | None]
    """The free-air reference at a P0 (Pa), if one was measured."""
    fault: Callable[[], Fault | None]
    """The latched fault, if any (what stopped a job)."""
    emit: Callable[[str, dict[str, Any]], None]
    """Publish an event (a task's progress, on the ``task`` topic)."""
    simulated: bool
    """The cell lays out its own objects and knows the truth (a simulated cell); on a real
    one the operator places the objects and ``truth`` is None."""
    place: Callable[[Any], Awaitable[None]]
    """Place a scene in front of the actuator (simulated cells; a real one refuses)."""
    lay_out: Callable[[Any], Awaitable[None]]
    """Lay out slots and objects for the arm to work in (simulated cells)."""
    truth: Callable[[], Awaitable[dict[str, Any] | None]]
    """What a simulated cell knows and a real one cannot (to score a run); None on a real cell."""
    move_l: Callable[[Sequence[float], float, float], Awaitable[None]]
    """Move the tool in a straight line ``(pose, speed m/s, acc m/s²)``; returns on arrival.
    Refused while a fault is latched, or without an arm."""
    tcp_pose: Callable[[], tuple[float, ...]]
    """The tool's pose now (refused without an arm)."""


OpenCell = Callable[[CellConfig, Backend], AbstractAsyncContextManager[TaskPort]]
"""A controller started on a cell (its config and backend) for one job, as its task port,
stopped when the job leaves it (service.open_cell)."""
