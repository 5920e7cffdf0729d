"""The dispatcher: a request from the command socket (requests/server.py checked its
framing, size and JSON) validated into its model and handed to the method that answers
it. It answers the requests on the cell as a whole here; the gripper's are grip.py's.

A refused request is an error reply. Anything else that raises while a request is
carried out is a bug: the cell is put in its safe state (an internal fault) and the
reply says so. While the daemon is still connecting to its devices only the requests
marked ``while_connecting`` (``status``, ``abort``, ``shutdown``) are accepted.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any, ClassVar, Literal

from fluidsense.common.errors import (
    CommandError,
    FluidsenseError,
    NotSupportedError,
    SequenceError,
)
from fluidsense.common.models import StrictModel
from fluidsense.common.scenes import Scene
from pydantic import Field

from .grip import GripHandler
from .jobs import TaskJobs
from .ports import DispatchPort
from .routing import Reply, Routes, answers, models_of, name_of

log = logging.getLogger(__name__)


class StatusRequest(StrictModel):
    cmd: Literal["status"]
    while_connecting: ClassVar[bool] = True


class CycleRequest(StrictModel):
    cmd: Literal["cycle"]
    p0_kpa: float | None = Field(None, ge=-101, le=1000)
    label: str | None = Field(None, max_length=80)
    store_reference: bool = False


class AbortRequest(StrictModel):
    cmd: Literal["abort"]
    reason: str = Field("operator", max_length=200)
    while_connecting: ClassVar[bool] = True


class ResetRequest(StrictModel):
    cmd: Literal["reset"]


class SceneRequest(StrictModel):
    cmd: Literal["scene"]
    scene: Scene


class TaskRequest(StrictModel):
    cmd: Literal["task"]
    file: str = Field(min_length=1, max_length=200, description="task file name in the daemon's task directory")
    order_mm: list[float] | None = Field(None, max_length=50)


class ShutdownRequest(StrictModel):
    cmd: Literal["shutdown"]
    while_connecting: ClassVar[bool] = True


class Dispatcher:
    def __init__(self, port: DispatchPort, grip: GripHandler, jobs: TaskJobs, *,
                 socket_stats: Callable[[], dict[str, int]] | None = None,
                 shutdown: Callable[[], None] | None = None):
        """``socket_stats``: the command socket's counts, for ``status``; ``shutdown``: what
        stops the daemon (none: the request is refused)."""
        self.port, self.grip, self.jobs = port, grip, jobs
        self._socket_stats, self._shutdown = socket_stats, shutdown
        self.routes = Routes(self, grip)

    async def answer(self, data: dict[str, Any]) -> Reply:
        """A request as the socket decoded it: its reply, or a FluidsenseError saying why not."""
        return await self.handle(self.routes.parse(data))

    async def handle(self, request: StrictModel) -> Reply:
        try:
            if not self.port.connected() and not getattr(request, "while_connecting", False):
                error = (self.port.connecting() or {}).get("error") or "first attempt under way"
                raise CommandError(f"not connected to {self.port.backend} yet ({error}); the daemon keeps trying: "
                                   "wait for status to leave 'connecting'")
            return await self.routes.method(request)(request)
        except FluidsenseError:
            raise
        except Exception as exc:  # noqa: BLE001
            name = getattr(request, "cmd", "?")
            log.exception("command %s failed", name)
            await self.port.fail(f"{type(exc).__name__} handling {name!r}: {exc}")
            raise CommandError(f"internal error: {type(exc).__name__}: {exc}; the cell was put in its safe state "
                               "(send reset to go on)") from exc

    # ------------------------------------------------------------------ the requests on the cell
    @answers(StatusRequest)
    async def status(self, req: StatusRequest) -> Reply:
        return {**self.port.status(), "task": self.jobs.status,
                "commands": None if self._socket_stats is None else self._socket_stats(), **self.grip.status()}

    @answers(CycleRequest)
    async def cycle(self, req: CycleRequest) -> Reply:
        fut = await self.port.start_cycle(p0_kpa=req.p0_kpa, label=req.label, store_reference=req.store_reference)
        fut.add_done_callback(lambda f: f.exception() if not f.cancelled() else None)
        return {"cycle_id": self.port.cycle.cycle_id}

    @answers(AbortRequest)
    async def abort(self, req: AbortRequest) -> Reply:
        stopped_task = self.jobs.cancel()
        return {"aborted": await self.port.abort(req.reason) or stopped_task}

    @answers(ResetRequest)
    async def reset(self, req: ResetRequest) -> Reply:
        self.port.reset()
        return {"state": self.port.cycle.state.value}

    @answers(SceneRequest)
    async def scene(self, req: SceneRequest) -> Reply:
        await self.port.place(req.scene)
        await self.grip.after_scene()
        return {"scene": req.scene.model_dump()}

    @answers(TaskRequest)
    async def task(self, req: TaskRequest) -> Reply:
        if self.grip.holding:
            raise SequenceError(f"holding (cycle {self.grip.cycle_id}): send release before a task")
        return self.jobs.start(req.file, req.order_mm)

    @answers(ShutdownRequest)
    async def shutdown(self, req: ShutdownRequest) -> Reply:
        if self._shutdown is None:
            raise NotSupportedError("this controller is not a daemon: nothing to shut down")
        self._shutdown()
        return {"shutting_down": True}

    # ------------------------------------------------------------------ lifecycle
    async def stop(self) -> None:
        """Before the controller stops: a running task is cancelled and awaited."""
        await self.jobs.stop()

    async def __aenter__(self) -> Dispatcher:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()


#: the command socket's requests, in the order the daemon lists them
REQUESTS = models_of(Dispatcher, GripHandler)
NAMES = tuple(name_of(m) for m in REQUESTS)
