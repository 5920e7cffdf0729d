"""Wiring: config -> backend -> controller (+ sockets). Used by the CLI and the tests."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import zmq

from controller.commands import CommandServer
from controller.config import CellConfig, load_cell_config
from controller.publisher import Publisher
from controller.service import Controller
from drivers.config import build_backend
from drivers.errors import CommandError, ConfigError, FaultError, FluidsenseError

from .notify import LoopWatchdog, Notifier, keep_alive

log = logging.getLogger(__name__)

REPO_ROOT = Path(__file__).resolve().parent.parent
DEFAULT_CONFIG = REPO_ROOT / "config" / "cell-sim.yaml"


def default_config_path() -> Path:
    local = Path("config/cell-sim.yaml")
    return local if local.exists() else DEFAULT_CONFIG


def load(path: str | Path | None, overrides: dict[str, Any] | None = None) -> CellConfig:
    return load_cell_config(path or default_config_path(), overrides)


@contextlib.asynccontextmanager
async def controller(cfg: CellConfig, publish: bool = False, record: bool = False,
                     pub_hwm: int | None = None) -> AsyncIterator[Controller]:
    """A started controller on the configured backend; vents and closes on exit. With
    ``record`` (the daemon) it records as ``cfg.recording`` says, from sample time 0.
    ``pub_hwm`` replaces the publisher's high-water mark (the soak bench fills it fast)."""
    pub = None
    if publish:
        try:
            pub = Publisher(cfg.publisher.pub, **({} if pub_hwm is None else {"hwm": pub_hwm}))
        except zmq.ZMQError as exc:
            raise ConfigError(f"publisher.pub: cannot bind {cfg.publisher.pub}: {exc}") from exc
    backend = build_backend(cfg.driver, cfg.profile.hardware)
    ctrl = Controller(cfg, backend, pub)
    try:
        if record and cfg.recording.enabled:
            from controller.recording import RecordingSink

            ctrl.add_sink(RecordingSink(cfg, backend.source, lambda: ctrl.references))
        async with ctrl:
            yield ctrl
    finally:
        if pub is not None:
            # the last message says where the valves were left, for whoever checks the safe state
            pub.send("log", ctrl.now, {"level": "INFO", "message": "controller stopped",
                                       "valves": backend.valves.state, "safe": backend.valves.in_safe_state})
            pub.close()


def _task_runner(ctrl: Controller, tasks_dir: Path):
    """Tasks started from the command socket: only YAML files in the task directory.
    The file is checked and loaded before anything starts, so a bad request gets an
    error reply instead of a failing task."""
    from tasks.config import load_task
    from tasks.runner import run_task

    root = tasks_dir.resolve()

    def start(name: str, order_mm):
        path = (root / name).resolve()
        if root not in path.parents or path.suffix not in (".yaml", ".yml") or not path.is_file():
            raise CommandError(f"task file {name!r} is not a YAML file in {root}")
        task = load_task(path)
        return run_task(ctrl, task, order_mm=order_mm)

    return start


async def _first_iteration(ctrl: Controller) -> None:
    """Real time: return once the sample loop has handled a block, so READY means the
    loop runs. A source that is down faults the cell instead; the daemon still serves
    (status, reset), so that is ready too. Virtual time parks the loop until asked."""
    if ctrl.virtual:
        return
    try:
        await ctrl.wait(0)
    except FaultError as exc:
        log.warning("ready without samples: %s", exc)


async def _until_stopped(ctrl: Controller, cfg: CellConfig, notifier: Notifier,
                         *ends: asyncio.Task) -> set[asyncio.Task]:
    """READY once the sample loop runs, watchdog pings while it makes progress, until one
    of ``ends`` finishes (a stop signal, a shutdown command, the command socket failing);
    returns the finished ones."""
    first = asyncio.create_task(_first_iteration(ctrl))
    done, _ = await asyncio.wait({first, *ends}, return_when=asyncio.FIRST_COMPLETED)
    first.cancel()
    if first not in done:
        return done
    running = f"profile {cfg.profile.name} on {ctrl.backend.name} ({'virtual' if ctrl.virtual else 'real'} time)"
    log.info("fluidsense running: %s", running)
    notifier.send("READY=1", f"STATUS=running: {running}")
    pinger = None
    if notifier.ping_period_s is not None:
        pinger = asyncio.create_task(keep_alive(notifier, LoopWatchdog(ctrl), notifier.ping_period_s),
                                     name="systemd-watchdog")
    try:
        done, _ = await asyncio.wait(set(ends), return_when=asyncio.FIRST_COMPLETED)
    finally:
        if pinger is not None:
            pinger.cancel()
    return done


async def run_daemon(cfg: CellConfig, tasks_dir: Path | None = None, notifier: Notifier | None = None) -> int:
    """The service: publish, accept commands, until SIGTERM/SIGINT or a shutdown command.
    Under systemd (``Type=notify``) it reports READY once both sockets are bound and the
    sample loop runs, pings the watchdog while the loop is alive, and STOPPING on the way out."""
    notifier = notifier or Notifier.from_env()
    tasks_dir = tasks_dir or REPO_ROOT / "config" / "tasks"
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    async with controller(cfg, publish=True, record=True) as ctrl:
        ctrl.task_runner = _task_runner(ctrl, tasks_dir)
        try:
            server = CommandServer(cfg.publisher.cmd, ctrl.handle_command, curve=cfg.publisher.cmd_curve)
        except (zmq.ZMQError, OSError, ValueError) as exc:
            raise ConfigError(f"publisher.cmd: cannot bind {cfg.publisher.cmd}: {exc}") from exc
        serve = asyncio.create_task(server.serve(), name="command-socket")
        stopper = asyncio.create_task(stop.wait())
        shutdown = asyncio.create_task(ctrl.wait_shutdown())
        done = await _until_stopped(ctrl, cfg, notifier, stopper, shutdown, serve)
        notifier.send("STOPPING=1", "STATUS=stopping: venting and closing")
        for task in (stopper, shutdown, serve):
            task.cancel()
        if serve in done and not serve.cancelled() and serve.exception() is not None:
            log.error("command socket failed: %s", serve.exception())
        server.close()
        log.info("stopping: venting and closing")
        fault = ctrl.fault
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.remove_signal_handler(sig)
    notifier.close()
    return 0 if fault is None or fault.kind != "driver" else 1


__all__ = ["FluidsenseError", "controller", "load", "run_daemon", "default_config_path"]
