"""The command dispatcher: a validated request (requests/server.py parses and checks it)
to the controller method that carries it out, and the daemon's task jobs.

A refused request is an error reply. Anything else that raises while a request is
carried out is a bug: the cell is put in its safe state (an internal fault) and the
reply says so. While the daemon is still connecting to its devices only ``status``,
``abort`` and ``shutdown`` are accepted.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Any

from fluidsense.common.errors import (
    CommandError,
    FluidsenseError,
    NotSupportedError,
    SequenceError,
)
from fluidsense.common.faults import Fault, FaultKind

from .gripper import Gripper
from .server import (
    AbortCmd,
    CycleCmd,
    GripCmd,
    MeasureCmd,
    ReleaseCmd,
    ResetCmd,
    SceneCmd,
    ShutdownCmd,
    StatusCmd,
    TaskCmd,
)

if TYPE_CHECKING:  # the controller wires this part; the type is only for reading
    from ..service import Controller

log = logging.getLogger(__name__)

#: the application installs this: (file, order_mm) -> a coroutine running the task (it
#: raises at once for a bad file); the controller never imports a task itself
TaskRunner = Callable[[str, list[float] | None], Awaitable[dict[str, Any]]]


class Dispatcher:
    def __init__(self, ctrl: Controller):
        self.ctrl = ctrl
        self.shutdown = asyncio.Event()
        self.task_runner: TaskRunner | None = None
        self._job: asyncio.Task | None = None
        self._job_name: str | None = None
        self.gripper = Gripper(ctrl)
        ctrl.telemetry.sinks.append(self.gripper)  # it watches every block of a grip

    async def handle(self, cmd: Any) -> dict[str, Any]:
        try:
            return await self._dispatch(cmd)
        except FluidsenseError:
            raise
        except Exception as exc:  # noqa: BLE001
            name = getattr(cmd, "cmd", "?")
            log.exception("command %s failed", name)
            await self.ctrl.latch.trip(Fault(FaultKind.INTERNAL, None, self.ctrl.now,
                                             f"{type(exc).__name__} handling {name!r}: {exc}"), self.ctrl.now)
            raise CommandError(f"internal error: {type(exc).__name__}: {exc}; the cell was put in its safe state "
                               "(send reset to go on)") from exc

    async def _dispatch(self, cmd: Any) -> dict[str, Any]:
        ctrl = self.ctrl
        if isinstance(cmd, StatusCmd):
            return ctrl.status()
        if not ctrl.connected and not isinstance(cmd, (ShutdownCmd, AbortCmd)):
            error = (ctrl.connecting or {}).get("error") or "first attempt under way"
            raise CommandError(f"not connected to {ctrl.backend.name} yet ({error}); the daemon keeps trying: "
                               "wait for status to leave 'connecting'")
        if isinstance(cmd, CycleCmd):
            fut = await ctrl.start_cycle(p0_kpa=cmd.p0_kpa, label=cmd.label, store_reference=cmd.store_reference)
            fut.add_done_callback(lambda f: f.exception() if not f.cancelled() else None)
            return {"cycle_id": ctrl.cycles.sequencer.cycle_id}
        if isinstance(cmd, GripCmd):
            return await self.gripper.grip(cmd.p0_kpa, cmd.timeout_s, cmd.label)
        if isinstance(cmd, ReleaseCmd):
            return await self.gripper.release()
        if isinstance(cmd, MeasureCmd):
            return await self.gripper.measure(cmd.p0_kpa, cmd.label, cmd.store_reference)
        if isinstance(cmd, AbortCmd):
            stopped_task = self.cancel_task()
            return {"aborted": await ctrl.abort(cmd.reason) or stopped_task}
        if isinstance(cmd, TaskCmd):
            return self.start_task(cmd.file, cmd.order_mm)
        if isinstance(cmd, ResetCmd):
            ctrl.reset()
            return {"state": ctrl.cycles.sequencer.state.value}
        if isinstance(cmd, SceneCmd):
            await ctrl.scene.place(cmd.scene)
            await self.gripper.after_scene()
            return {"scene": cmd.scene.model_dump()}
        if isinstance(cmd, ShutdownCmd):
            self.shutdown.set()
            return {"shutting_down": True}
        raise CommandError(f"unhandled command {cmd!r}")  # pragma: no cover

    # ------------------------------------------------------------------ task jobs
    @property
    def task(self) -> dict[str, Any] | None:
        return None if self._job is None else {"file": self._job_name, "running": not self._job.done()}

    def start_task(self, file: str, order_mm: list[float] | None) -> dict[str, Any]:
        ctrl = self.ctrl
        if self.task_runner is None:
            raise NotSupportedError("this daemon runs no tasks")
        if self._job is not None and not self._job.done():
            raise SequenceError(f"busy: task {self._job_name} is running")
        if self.gripper.holding:
            raise SequenceError(f"holding (cycle {self.gripper.cycle_id}): send release before a task")
        if ctrl.cycles.busy:
            raise SequenceError(f"busy: cycle {ctrl.cycles.sequencer.cycle_id} is in "
                                f"{ctrl.cycles.sequencer.state.value}")
        work = self.task_runner(file, order_mm)  # raises here for a bad file: an error reply

        async def job() -> None:
            try:
                await work
            except asyncio.CancelledError:
                ctrl.telemetry.emit("task", {"task": file, "event": "aborted"})
                raise
            except FluidsenseError as exc:  # the task could not go on: reported; the daemon goes on
                log.error("task %s failed: %s", file, exc)
                if ctrl.cycles.busy:
                    await ctrl.abort(f"task failed: {exc}")
            except Exception as exc:  # noqa: BLE001 - a bug in a task: vent, say why
                log.exception("task %s failed", file)
                await ctrl.latch.trip(Fault(FaultKind.INTERNAL, None, ctrl.now,
                                            f"task {file}: {type(exc).__name__}: {exc}"), ctrl.now)

        self._job_name = file
        self._job = asyncio.get_running_loop().create_task(job(), name=f"task {file}")
        return {"task": file, "started": True}

    def cancel_task(self) -> bool:
        if self._job is None or self._job.done():
            return False
        self._job.cancel()
        return True

    async def stop(self) -> None:
        if self.cancel_task():
            try:
                await self._job
            except (asyncio.CancelledError, Exception):  # noqa: BLE001 - stopping anyway
                pass
