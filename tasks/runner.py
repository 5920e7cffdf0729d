"""Run a task file on the controller (through its task port), publishing progress on the
``task`` topic."""

from __future__ import annotations

import logging
from typing import Any

from fluidsense.common.errors import CommandError, JobStopped
from fluidsense.controller.ports import TaskPort

from .closed_loop import TASKS
from .stopping import fault_dict, stopped_message

log = logging.getLogger(__name__)


async def run_task(port: TaskPort, task, order_mm: list[float] | None = None) -> dict[str, Any]:
    """Run ``task`` (a loaded task file); returns its JSON-ready summary. A task that cannot
    finish raises JobStopped with the steps it completed and the fault that stopped it."""
    fn = TASKS[task.task]
    if order_mm is not None and task.task != "sorting":
        raise CommandError("--order applies to sorting tasks only")
    steps: list[dict[str, Any]] = []

    def report(event: dict[str, Any]) -> None:
        steps.append(event)
        port.emit("task", {"task": task.task, "step": len(steps), **event})

    report({"event": "started"})
    try:
        kwargs = {"order_mm": order_mm} if task.task == "sorting" else {}
        summary = await fn(port, task, report, **kwargs)
    except Exception as exc:
        fault = fault_dict(port)
        error = f"{type(exc).__name__}: {exc}"
        message = stopped_message(f"task {task.task}", port, exc, f"{len(steps) - 1} step(s)")
        partial = {"task": task.task, "completed": False, "error": error, "fault": fault, "t_s": port.now(),
                   "steps": steps[1:]}
        report({"event": "failed", "error": error, "fault": fault})
        raise JobStopped(message, partial, fault) from exc
    report({"event": "finished", "summary": summary})
    log.info("task %s finished in %.1f s of sample time", task.task, summary.get("duration_s", 0.0))
    return summary
