"""What each request handler reads of the cell and what it may ask of it.

A port is a small object of callables, named for the handler that holds it: wiring.py
builds each from the controller, a test builds them from a fake (tests/support/requests.py).
A handler holds its port (``self.port``) and nothing else of the controller, so what it can
touch is what its port lists. (What handlers read of each other, the dispatcher of the
gripper and the gripper of the task jobs, they are handed when wiring.py assembles them.)
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
    """The gripper's (grip.GripHandler): it starts cycles and follows them, block by block
    (the blocks come through the controller's sample path: controller/path.py
    BlockWatcher)."""

    now: Callable[[], float]
    """Sample time (s): the newest sample's timestamp."""
    virtual: bool
    """Virtual time: sample time stands still unless something waits on it."""
    cycle: RunningCycle
    """The running cycle, as the sequencer runs it (read only)."""
    reference: Callable[[float], Reference | None]
    """The free-air reference at a P0 (Pa), if one was measured."""
    start_cycle: StartCycle
    """Start a cycle ``(p0_kpa, label, store_reference, hold)``: the future of its result."""
    measured: Callable[[], Awaitable[CycleResult]]
    """The running cycle's features, once its measurement windows have closed."""
    let_go: Callable[[], Awaitable[Any]]
    """A held cycle vents; not waited for."""
    abort: Callable[[str], Awaitable[bool]]
    """Abort the running cycle (vent), saying why; False when none was running."""
    wait: Callable[[float], Awaitable[None]]
    """Wait this many seconds of sample time."""
    fail: Callable[[str], Awaitable[None]]
    """A bug: vent and latch an internal fault saying this."""
    emit: Emit
    """Publish an event (``contact``, ``grasp``, ``slip``, ``released``)."""


@dataclass(frozen=True)
class JobPort:
    """The task jobs' (jobs.TaskJobs): a task runs on the controller itself (through its own
    port, controller/ports.py TaskPort); its job only reports and stops it."""

    cycle: RunningCycle
    """The running cycle (read only): a task may not start over a busy one."""
    abort: Callable[[str], Awaitable[bool]]
    """Abort the running cycle (vent), saying why."""
    fail: Callable[[str], Awaitable[None]]
    """A bug in a task: vent and latch an internal fault saying this."""
    emit: Emit
    """Publish an event (a task's ``aborted``)."""


@dataclass(frozen=True)
class DispatchPort:
    """The dispatcher's (dispatch.Dispatcher): the requests on the cell as a whole."""

    backend: str
    """The backend's name (the cell's driver), for replies."""
    connected: Callable[[], bool]
    """The devices are connected (until then most requests are refused)."""
    connecting: Callable[[], dict[str, Any] | None]
    """While connecting: the attempts and the last error."""
    cycle: RunningCycle
    """The running cycle (read only)."""
    status: Callable[[], dict[str, Any]]
    """The controller's own part of ``status``."""
    start_cycle: StartCycle
    """Start a cycle ``(p0_kpa, label, store_reference, hold)``: the future of its result."""
    abort: Callable[[str], Awaitable[bool]]
    """Abort the running cycle (vent), saying why; False when none was running."""
    reset: Callable[[], None]
    """Clear a latched fault (refused until the device confirms the safe state)."""
    place: Callable[[Any], Awaitable[None]]
    """Place a scene in front of the actuator (simulated cells)."""
    fail: Callable[[str], Awaitable[None]]
    """A bug: vent and latch an internal fault saying this."""
