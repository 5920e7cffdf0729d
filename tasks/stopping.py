"""How a job (a task, a calibration, a sensing run) says that something stopped it."""

from __future__ import annotations

from typing import Any

from fluidsense.controller.ports import TaskPort


def fault_dict(port: TaskPort) -> dict[str, Any] | None:
    """The latched fault, as jobs report it."""
    f = port.fault()
    return None if f is None else {"kind": str(f.kind), "detail": f.detail, "t_s": f.t}


def stopped_message(what: str, port: TaskPort, exc: BaseException, done: str) -> str:
    """One line: what stopped, by which fault (when one is latched) and when, what was done."""
    f = port.fault()
    cause = f"fault {f.kind} at t={f.t:.2f} s ({f.detail})" if f is not None else f"{type(exc).__name__}: {exc}"
    return f"{what} stopped by {cause} after {done}; the cell was left in its safe state"
