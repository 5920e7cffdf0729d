"""Tasks started from the command socket, one at a time.

The daemon hands in the runner ((file, order_mm) -> a coroutine running the task; it
raises at once for a bad file, so a bad request gets an error reply); the controller never
imports a task itself. A task that cannot go on is reported and the daemon goes on; a bug
in one vents the cell and says why.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable
from typing import Any

from fluidsense.common.errors import FluidsenseError, NotSupportedError, SequenceError

from .ports import JobPort

log = logging.getLogger(__name__)

TaskRunner = Callable[[str, list[float] | None], Awaitable[dict[str, Any]]]


class TaskJobs:
    def __init__(self, port: JobPort, runner: TaskRunner | None):
        self.port, self.runner = port, runner
        self._job: asyncio.Task | None = None
        self._file: str | None = None

    @property
    def status(self) -> dict[str, Any] | None:
        """The last task started: its file, and whether it still runs."""
        return None if self._job is None else {"file": self._file, "running": not self._job.done()}

    def running(self) -> str | None:
        """The file of the task that runs, if one does."""
        return self._file if self._job is not None and not self._job.done() else None

    def start(self, file: str, order_mm: list[float] | None) -> dict[str, Any]:
        cycle = self.port.cycle
        if self.runner is None:
            raise NotSupportedError("this daemon runs no tasks")
        if self.running() is not None:
            raise SequenceError(f"busy: task {self._file} is running")
        if cycle.busy:
            raise SequenceError(f"busy: cycle {cycle.cycle_id} is in {cycle.state.value}")
        work = self.runner(file, order_mm)  # raises here for a bad file: an error reply
        self._file = file
        self._job = asyncio.get_running_loop().create_task(self._run(file, work), name=f"task {file}")
        return {"task": file, "started": True}

    async def _run(self, file: str, work: Awaitable[dict[str, Any]]) -> None:
        try:
            await work
        except asyncio.CancelledError:
            self.port.emit("task", {"task": file, "event": "aborted"})
            raise
        except FluidsenseError as exc:  # the task could not go on: reported; the daemon goes on
            log.error("task %s failed: %s", file, exc)
            if self.port.cycle.busy:
                await self.port.abort(f"task failed: {exc}")
        except Exception as exc:  # noqa: BLE001 - a bug in a task: vent, say why
            log.exception("task %s failed", file)
            await self.port.fail(f"task {file}: {type(exc).__name__}: {exc}")

    def cancel(self) -> bool:
        if self._job is None or self._job.done():
            return False
        self._job.cancel()
        return True

    async def stop(self) -> None:
        if self.cancel():
            try:
                await self._job
            except (asyncio.CancelledError, Exception):  # noqa: BLE001 - stopping anyway
                pass
