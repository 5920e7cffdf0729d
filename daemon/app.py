"""Wiring: config -> backend -> controller (+ sockets). Used by the CLI and the tests."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import zmq
from fluidsense.common import stopsignals
from fluidsense.common.errors import (
    CommandError,
    ConfigError,
    FaultError,
    FluidsenseError,
)
from fluidsense.common.exitcodes import EXIT_FAILURE, EXIT_OK
from fluidsense.config import SHIPPED
from fluidsense.controller.config import CellConfig, load_cell_config
from fluidsense.controller.cycles.kept import default_path as default_references_path
from fluidsense.controller.requests.server import CommandServer
from fluidsense.controller.requests.wiring import wire
from fluidsense.controller.safety.latch import vented_word
from fluidsense.controller.service import Controller
from fluidsense.controller.telemetry.publisher import Publisher
from fluidsense.drivers.registry import build_backend

from .notify import LoopWatchdog, Notifier, keep_alive

log = logging.getLogger(__name__)

DEFAULT_CONFIG = SHIPPED / "cell-sim.yaml"
TASKS_DIR = SHIPPED / "tasks"


def default_config_path() -> Path:
    local = Path("config/cell-sim.yaml")
    return local if local.exists() else DEFAULT_CONFIG


def load(path: str | Path | None, overrides: dict[str, Any] | None = None) -> CellConfig:
    return load_cell_config(path or default_config_path(), overrides)


def _loop_priority(cfg: CellConfig) -> dict[str, Any]:
    """The sample loop's thread at real-time priority when permitted (``loop.rt_priority``):
    on a busy robot PC a loop at normal priority falls behind its samples. Processes
    started from here (sampler, ur_rtde worker, publisher outlet) get the normal policy
    back and set their own."""
    from fluidsense.drivers.sampler.realtime import set_loop_priority

    result = set_loop_priority(cfg.loop.rt_priority)
    if result["applied"]:
        log.info("sample loop: %s", result["detail"])
    elif result["requested"]:
        log.warning("sample loop at normal priority: %s", result["detail"])
    return result


def bind_publisher(cfg: CellConfig, hwm: int | None = None) -> Publisher:
    try:
        return Publisher(cfg.publisher.pub, hwm=cfg.publisher.hwm_messages if hwm is None else hwm)
    except zmq.ZMQError as exc:
        raise ConfigError(f"publisher.pub: cannot bind {cfg.publisher.pub}: {exc}") from exc


def bind_command_server(cfg: CellConfig, instance: str | None = None) -> CommandServer:
    """The command socket, bound; it serves once the controller runs. ``instance``: the
    daemon's id (its publisher's), which its replies carry."""
    try:
        return CommandServer(cfg.publisher.cmd, curve=cfg.publisher.cmd_curve, instance=instance)
    except (zmq.ZMQError, OSError, ValueError) as exc:
        raise ConfigError(f"publisher.cmd: cannot bind {cfg.publisher.cmd}: {exc}") from exc


@contextlib.asynccontextmanager
async def controller(cfg: CellConfig, publish: bool = False, record: bool = False,
                     pub_hwm: int | None = None, publisher: Publisher | None = None,
                     connect_in_background: bool = False, own_process: bool = False,
                     keep_references: bool = False) -> AsyncIterator[Controller]:
    """A started controller on the configured backend; vents and closes on exit. With
    ``record`` (the daemon) it records as ``cfg.recording`` says, from sample time 0.
    ``publisher``: already bound (the daemon binds every socket before it touches a
    device); else ``publish`` binds one here, with ``pub_hwm`` as its high-water mark
    (the soak bench fills it fast). Whatever fails on the way in, what was started is
    undone: the devices vented and closed, the sockets closed. ``connect_in_background``
    (the daemon): devices that are not there yet are retried by the loop (status
    ``connecting``) instead of failing the start. ``own_process`` (the daemon, a CLI job):
    this process exists for the controller, whose loop then asks for real-time priority
    (``loop.rt_priority``); a library caller (a test, a bench) keeps its own scheduling.
    ``keep_references`` (the daemon): free-air references kept on disk as ``references``
    says, and those there that still belong to the cell taken back."""
    pub = publisher or (bind_publisher(cfg, pub_hwm) if publish else None)
    ctrl: Controller | None = None
    try:
        backend = build_backend(cfg.driver, cfg.profile.hardware)
        realtime = _loop_priority(cfg) if own_process and not backend.source.virtual else None
        ctrl = Controller(cfg, backend, pub)
        if keep_references:
            ctrl.keep_references(default_references_path(cfg))
        if realtime is not None:  # status and the heartbeat say it, not only the log
            ctrl.use_realtime(realtime, cfg.loop.rt_priority)
        try:
            await ctrl.start(connect_in_background)
        except BaseException:  # a stop signal while connecting included: vent what was set up, close it
            await ctrl.stop()
            raise
        try:
            if record and cfg.recording.enabled:
                from fluidsense.controller.telemetry.queued import QueuedSink
                from fluidsense.drivers.recording.sink import RecordingSink

                # no await since start(): the loop has not handled a block yet. The writer
                # thread reads the references: dict() copies them in one step under the GIL
                sink = RecordingSink(cfg.recording, cfg.model_dump(mode="json"), CellConfig.model_json_schema(),
                                     backend.source, lambda: dict(ctrl.cycles.references))
                ctrl.add_sink(QueuedSink(sink, wait_when_full=backend.source.virtual))
            yield ctrl
        finally:
            await ctrl.stop()
    finally:
        if pub is not None:
            if ctrl is not None:
                # the last message says where the valves were left, for whoever checks the safe state
                valves = ctrl.backend.valves
                pub.send("log", ctrl.now, {"level": "INFO", "message": "controller stopped",
                                           "valves": valves.state, "safe": valves.in_safe_state,
                                           "valves_reported": valves.reported,
                                           "vented": vented_word(ctrl.latch.vented())})
            if publisher is None:
                pub.close()


def _task_runner(ctrl: Controller, tasks_dir: Path):
    """Tasks started from the command socket: only YAML files in the task directory.
    The file is checked and loaded before anything starts, so a bad request gets an
    error reply instead of a failing task."""
    from fluidsense.tasks.config import load_task
    from fluidsense.tasks.runner import run_task

    root = tasks_dir.resolve()

    def start(name: str, order_mm):
        path = (root / name).resolve()
        if root not in path.parents or path.suffix not in (".yaml", ".yml") or not path.is_file():
            raise CommandError(f"task file {name!r} is not a YAML file in {root}")
        task = load_task(path)
        return run_task(ctrl.task_port, task, order_mm=order_mm)

    return start


async def _first_iteration(ctrl: Controller, notifier: Notifier) -> None:
    """Return once the devices are connected and (real time) the sample loop has handled
    a block, so READY means the cell can act. Until then systemd's STATUS says what the
    daemon is waiting for. Virtual time parks the loop until asked."""
    said = None
    while not ctrl.connected:
        if ctrl.connecting is not None and ctrl.connecting["error"] != said:
            said = ctrl.connecting["error"]
            notifier.send(f"STATUS=connecting to {ctrl.backend.name}: {said}")
        if ctrl.loop_task.done():
            return  # the loop ended while connecting: the daemon stops, not ready
        await asyncio.sleep(0.1)  # polling the connection state for systemd's STATUS line
    if ctrl.virtual:
        return
    try:
        await ctrl.wait(0)
    except FaultError as exc:
        log.warning("ready without samples: %s", exc)
    except CommandError:  # the loop ended before its first block: the daemon stops, not ready
        pass


async def _until_stopped(ctrl: Controller, cfg: CellConfig, notifier: Notifier,
                         *ends: asyncio.Task) -> set[asyncio.Task]:
    """READY once the sample loop runs, watchdog pings while it makes progress, until one
    of ``ends`` finishes (a stop signal or a shutdown request, the command socket failing);
    returns the finished ones."""
    first = asyncio.create_task(_first_iteration(ctrl, notifier))
    done, _ = await asyncio.wait({first, *ends}, return_when=asyncio.FIRST_COMPLETED)
    first.cancel()
    if first not in done:
        return done
    running = f"profile {cfg.profile.name} on {ctrl.backend.name} ({'virtual' if ctrl.virtual else 'real'} time)"
    log.info("fluidsense running: %s", running)
    notifier.send("READY=1", f"STATUS=running: {running}")
    pinger = None
    if notifier.ping_period_s is not None:
        pinger = asyncio.create_task(keep_alive(notifier, LoopWatchdog(ctrl.loop), notifier.ping_period_s),
                                     name="systemd-watchdog")
    try:
        done, _ = await asyncio.wait(set(ends), return_when=asyncio.FIRST_COMPLETED)
    finally:
        if pinger is not None:
            pinger.cancel()
    return done


async def run_daemon(cfg: CellConfig, tasks_dir: Path | None = None, notifier: Notifier | None = None,
                     own_process: bool = False) -> int:
    """The service: publish, accept commands, until a stop signal (SIGTERM, SIGINT, SIGHUP:
    common/stopsignals.py, as the CLI jobs) or a shutdown command.
    Both sockets are bound before any device is touched; a failure on the way in undoes
    what was started. Under systemd (``Type=notify``) it reports READY once the sample
    loop runs, pings the watchdog while the loop is alive, and STOPPING on the way out.

    Returns 0 after a requested stop. A core task that ends by itself (the sample loop or
    the command socket: a bug) stops the daemon the same way, vented, and returns 1, so
    that systemd's ``Restart=on-failure`` starts it again."""
    notifier = notifier or Notifier.from_env()
    tasks_dir = tasks_dir or TASKS_DIR
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    pub = bind_publisher(cfg)
    try:
        server = bind_command_server(cfg, pub.instance)
    except BaseException:
        pub.close()
        raise
    try:
        live = _start_live(cfg)
    except BaseException:
        server.close()
        pub.close()
        raise
    signals = contextlib.ExitStack()  # the stop signals' handlers, removed on the way out
    signals.enter_context(stopsignals.handle_stop_signals(loop, lambda _: stop.set()))
    failed: list[str] = []
    bad_setting: ConfigError | None = None
    try:
        async with controller(cfg, publisher=pub, record=True, connect_in_background=True,
                              own_process=own_process, keep_references=True) as ctrl, \
                wire(ctrl, tasks=_task_runner(ctrl, tasks_dir), socket_stats=lambda: server.stats,
                     shutdown=stop.set) as requests:
            if live is not None:  # no await since start(): the view's times are the recording's
                ctrl.add_sink(_share_clock(ctrl, live))
            serve = asyncio.create_task(server.serve(requests.answer), name="command-socket")
            stopper = asyncio.create_task(stop.wait(), name="stop-signal")
            core = {serve: "the command socket", ctrl.loop_task: "the sample loop"}
            done = await _until_stopped(ctrl, cfg, notifier, stopper, *core)
            notifier.send("STOPPING=1", "STATUS=stopping: venting and closing")
            for task, name in core.items():
                if task in done:
                    cause = task.exception() if not task.cancelled() else None
                    if isinstance(cause, ConfigError):  # found on connecting: retrying will not mend it
                        bad_setting = cause
                        continue
                    failed.append(f"{name} ended: {cause!r}" if cause is not None else f"{name} ended")
            for task in (stopper, serve):
                task.cancel()
            for reason in failed:
                log.critical("%s; venting and exiting with status 1 for a restart", reason)
            log.info("stopping: venting and closing")
    finally:
        server.close()
        pub.close()
        if live is not None:  # closed already if the controller got to close its sinks
            live.close()
        signals.close()
        notifier.close()
    if bad_setting is not None:
        raise bad_setting
    return EXIT_FAILURE if failed else EXIT_OK


def _start_live(cfg: CellConfig):
    """The live view's process, bound with the daemon's sockets (before any device)."""
    if not cfg.live.enabled:
        return None
    from fluidsense.controller.telemetry.live import LiveSink

    return LiveSink(cfg.live)


def _share_clock(ctrl: Controller, live):
    """The live view takes the recording's wall clock at sample time 0, so that a viewer
    shows the live daemon and its file on the same timeline."""
    for sink in ctrl.telemetry.sinks:
        t0 = getattr(getattr(sink, "inner", sink), "t0_unix_ns", None)  # the recording, behind its queue
        if t0 is not None:
            live.set_t0(t0)
    return live


__all__ = ["FluidsenseError", "controller", "load", "run_daemon", "default_config_path"]
