"""The request layer wired: the handlers on their ports (ports.py), one dispatcher in
front. ``wire`` builds the ports from a controller (the daemon does this once its
controller runs, daemon/app.py); a test builds them from a fake and calls ``assemble``.

This is the one place that knows both sides: the handlers know their ports, the
controller knows nothing of the requests.
"""

from __future__ import annotations

from collections.abc import Callable

from ..config import Profile
from ..config.gripper import GripperConfig
from ..service import Controller
from .dispatch import Dispatcher
from .grip import GripHandler
from .jobs import TaskJobs, TaskRunner
from .ports import DispatchPort, GripPort, JobPort


def assemble(dispatch: DispatchPort, grip: GripPort, jobs: JobPort, gripper: GripperConfig, profile: Profile, *,
             tasks: TaskRunner | None = None, socket_stats: Callable[[], dict[str, int]] | None = None,
             shutdown: Callable[[], None] | None = None) -> Dispatcher:
    """The handlers on their ports. ``tasks`` runs a task file (none: ``task`` is refused);
    ``socket_stats`` and ``shutdown``: see Dispatcher."""
    task_jobs = TaskJobs(jobs, tasks)
    handler = GripHandler(grip, gripper, profile, running_task=task_jobs.running)
    return Dispatcher(dispatch, handler, task_jobs, socket_stats=socket_stats, shutdown=shutdown)


def wire(ctrl: Controller, *, tasks: TaskRunner | None = None, socket_stats: Callable[[], dict[str, int]] | None = None,
         shutdown: Callable[[], None] | None = None) -> Dispatcher:
    """The dispatcher that answers requests on ``ctrl``; its gripper watches the blocks
    (one of the controller's block watchers: path.py BlockWatcher, beside the telemetry).
    Use it as ``async with``: a task it started is stopped before the controller is."""
    cycle = ctrl.cycles.sequencer
    requests = assemble(
        DispatchPort(backend=ctrl.backend.name, connected=lambda: ctrl.connected, connecting=lambda: ctrl.connecting,
                     cycle=cycle, status=ctrl.status, start_cycle=ctrl.start_cycle, abort=ctrl.abort, reset=ctrl.reset,
                     place=ctrl.scene.place, fail=ctrl.fail),
        GripPort(now=lambda: ctrl.now, virtual=ctrl.virtual, cycle=cycle, reference=ctrl.reference,
                 start_cycle=ctrl.start_cycle, measured=ctrl.measured, let_go=ctrl.let_go, abort=ctrl.abort,
                 wait=ctrl.wait, fail=ctrl.fail, emit=ctrl.emit),
        JobPort(cycle=cycle, abort=ctrl.abort, fail=ctrl.fail, emit=ctrl.emit),
        ctrl.cfg.gripper, ctrl.profile, tasks=tasks, socket_stats=socket_stats, shutdown=shutdown)
    ctrl.watch(requests.grip)
    return requests
