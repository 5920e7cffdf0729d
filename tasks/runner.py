"""Run a task file on a controller, publishing progress on the ``task`` topic."""

from __future__ import annotations

import logging
from typing import Any

from controller.service import Controller
from drivers.errors import CommandError

from .closed_loop import TASKS

log = logging.getLogger(__name__)


async def run_task(ctrl: Controller, task, order_mm: list[float] | None = None) -> dict[str, Any]:
    """Run ``task`` (a loaded task file); returns its JSON-ready summary."""
    fn = TASKS[task.task]
    seq = {"n": 0}

    def report(event: dict[str, Any]) -> None:
        seq["n"] += 1
        ctrl.emit("task", {"task": task.task, "step": seq["n"], **event})

    report({"event": "started"})
    try:
        if task.task == "sorting":
            summary = await fn(ctrl, task, report, order_mm=order_mm)
        else:
            if order_mm is not None:
                raise CommandError("--order applies to sorting tasks only")
            summary = await fn(ctrl, task, report)
    except Exception as exc:
        report({"event": "failed", "error": f"{type(exc).__name__}: {exc}"})
        raise
    report({"event": "finished", "summary": summary})
    log.info("task %s finished in %.1f s of sample time", task.task, summary.get("duration_s", 0.0))
    return summary
