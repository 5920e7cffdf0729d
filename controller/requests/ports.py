"""What each request handler reads of the cell and what it may ask of it.

A port is a small object of callables: wiring.py builds each from the controller, a test
builds them from a fake (tests/support/requests.py). A handler holds its port and nothing
else of the controller, so what it can touch is what its port lists. (What handlers read
of each other, the dispatcher of the gripper and the gripper of the task jobs, they are
handed when wiring.py assembles them.)
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any, Protocol

from ..cycles.analysis import CycleResult, Reference
from ..cycles.sequencer import State

Emit = Callable[[str, dict[str, Any]], None]
StartCycle = Callable[..., Awaitable[asyncio.Future[CycleResult]]]  # (p0_kpa, label, store_reference, hold)


class RunningCycle(Protocol):
    """The cycle as the sequencer runs it; read only."""

    @property
    def state(self) -> State: ...

    @property
    def cycle_id(self) -> int: ...

    @property
    def p0_pa(self) -> float: ...

    @property
    def t_open(self) -> float | None: ...

    @property
    def busy(self) -> bool: ...


@dataclass(frozen=True)
class GripPort:
    """The gripper's: it follows the cycles it starts, block by block."""

    now: Callable[[], float]
    virtual: bool  # sample time stands still unless something waits on it
    cycle: RunningCycle
    reference: Callable[[float], Reference | None]  # the free-air reference at a P0 (Pa)
    start_cycle: StartCycle
    measured: Callable[[], Awaitable[CycleResult]]  # the running cycle's features, once measured
    let_go: Callable[[], Awaitable[Any]]  # a held cycle vents; not waited for
    abort: Callable[[str], Awaitable[bool]]
    wait: Callable[[float], Awaitable[None]]  # seconds of sample time
    fail: Callable[[str], Awaitable[None]]  # a bug: vent and latch an internal fault saying this
    emit: Emit


@dataclass(frozen=True)
class JobPort:
    """The task jobs': a task runs on the controller itself; its job only reports and
    stops it."""

    cycle: RunningCycle
    abort: Callable[[str], Awaitable[bool]]
    fail: Callable[[str], Awaitable[None]]
    emit: Emit


@dataclass(frozen=True)
class CellPort:
    """The dispatcher's: the requests on the cell as a whole."""

    backend: str  # its name
    connected: Callable[[], bool]
    connecting: Callable[[], dict[str, Any] | None]  # attempts and the last error, while connecting
    cycle: RunningCycle
    status: Callable[[], dict[str, Any]]  # the controller's own part of ``status``
    start_cycle: StartCycle
    abort: Callable[[str], Awaitable[bool]]
    reset: Callable[[], None]
    place: Callable[[Any], Awaitable[None]]  # a scene (simulated cells)
    fail: Callable[[str], Awaitable[None]]
