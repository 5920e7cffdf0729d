"""The controller service: sample loop, sequencer, features, publishing, commands.

Data flow per block:  source -> supervisor -> sequencer (commands to the devices)
-> recorder -> features at cycle end -> publisher.

The controller's "now" is the timestamp of the newest sample. In virtual time the loop
only pulls samples while something is waiting on the clock (a cycle, a wait, a task);
when nothing is, virtual time stands still, which makes every run reproducible.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import replace
from typing import Any

import numpy as np

from drivers.base import Backend, SampleBlock
from drivers.errors import (CommandError, DeviceTimeoutError, FaultError, FluidsenseError, LinkLostError,
                            NotSupportedError, SafetyError, SequenceError)
from drivers.faults import Fault, FaultKind

from .commands import AbortCmd, CycleCmd, ResetCmd, SceneCmd, ShutdownCmd, StatusCmd, TaskCmd
from .config import CellConfig
from .cycle import CycleResult, Recorder, Reference, analyse, make_reference, transition_dict
from .latch import SafetyLatch, vented_word
from .publisher import NullPublisher, Publisher
from .sequencer import Command, FlowProfileCmd, Sequencer, SetpointCmd, State, ValveCmd
from .supervisor import Supervisor

log = logging.getLogger(__name__)

KPA = 1e3


_EDGE_SCALE = {"kPa": KPA, "SLPM": 1e-3 / 60.0}


def _unit(channel: str) -> str:
    """Unit of a channel at the published edge: pressures in kPa, flows in SLPM."""
    return "SLPM" if channel.startswith("flow") else "kPa"


def _reference_key(p0_pa: float) -> float:
    return round(p0_pa / KPA, 3)


def _word(open_: bool) -> str:
    return "open" if open_ else "closed"


def _command_dict(cmd: Command) -> dict[str, Any]:
    if isinstance(cmd, ValveCmd):
        return {"kind": "valve", "valve": cmd.valve, "open": cmd.open}
    if isinstance(cmd, SetpointCmd):
        return {"kind": "setpoint", "pressure_pa": cmd.pressure_pa}
    return {"kind": "flow_profile", "times_s": list(cmd.times), "flows_m3_s": list(cmd.flows)}


class Sink:
    """Something that keeps what the controller sees (a recorder, a test probe). Every
    method is called from the sample loop and must return quickly; a sink that raises is
    logged and dropped rather than allowed to stop the loop.

    ``on_event`` gets every published event and two that are not published, which a
    recording needs to replay a cycle exactly: ``cycle_start`` (cycle_id, p0_pa, label,
    store_reference, hold) and ``command`` (each command sent to a device)."""

    def on_block(self, block: SampleBlock) -> None: ...

    def on_event(self, topic: str, t_s: float, payload: dict[str, Any]) -> None: ...

    def flush(self, t_s: float) -> None: ...

    def close(self) -> None: ...


class SampleClock:
    """The controller's clock as devices see it: ``now`` is the newest sample's time and
    ``wait_until`` returns once samples have reached a time (in virtual time it also
    keeps sample time running until then)."""

    def __init__(self, ctrl: Controller):
        self._ctrl = ctrl

    @property
    def now(self) -> float:
        return self._ctrl.now

    async def wait_until(self, t: float) -> None:
        await self._ctrl.wait(t - self._ctrl.now)


class Controller:
    def __init__(self, cfg: CellConfig, backend: Backend, publisher: Publisher | NullPublisher | None = None):
        self.cfg = cfg
        self.profile = cfg.profile
        self.backend = backend
        self.pub = publisher or NullPublisher()
        self.sequencer = Sequencer(self.profile.sequence, backend.valves.safe_positions)
        self.supervisor = Supervisor(self.profile, cfg.supervision)
        self._wall_lag0: float | None = None  # wall-clock minus sample time of the earliest block
        self.now = 0.0
        self.references: dict[float, Reference] = {}
        self.results: deque[CycleResult] = deque(maxlen=100)
        self.latch = SafetyLatch(backend)
        self._stopping = False
        self.connected = False  # the devices are set up (start(), or the loop's first act)
        self.connecting: dict[str, Any] | None = None  # while not connected: attempts, last error, next wait
        self._recorder: Recorder | None = None
        self._cycle_future: asyncio.Future[CycleResult] | None = None
        self._cycle_opts: dict[str, Any] = {}
        self._waiters: list[tuple[float, asyncio.Future[None]]] = []
        self._demand = asyncio.Event()
        self._task: asyncio.Task[None] | None = None
        self._shutdown = asyncio.Event()
        # statistics for the heartbeat
        self.samples = 0
        self.blocks = 0
        self.missed = 0
        self.late = 0
        self._proc_s: deque[float] = deque(maxlen=2000)
        self.loop_ticks = 0  # iterations the sample loop completed (a block, or a failed read handled)
        self._parked = False  # the loop waits for demand (virtual time, nothing waits on samples)
        self._next_heartbeat = 0.0
        self._batch: list[SampleBlock] = []
        self._batch_start: float | None = None
        self._started_wall = time.monotonic()
        self.clock = SampleClock(self)
        # the application installs this: (file, order_mm) -> coroutine running a task (it
        # raises at once for a bad file); the controller never imports a task itself
        self.task_runner: Callable[[str, list[float] | None], Awaitable[dict[str, Any]]] | None = None
        self._task_job: asyncio.Task | None = None
        self._task_name: str | None = None
        self.sinks: list[Sink] = []
        self._measured: asyncio.Future[CycleResult] | None = None
        self._hold = False
        # background I/O started from the loop: reading the valve outputs back, kicking the box watchdog
        self._readback: asyncio.Task | None = None
        self._kick: asyncio.Task | None = None
        self._next_kick = 0.0
        self._vented_seen: bool | None = None  # the last ``vented`` published, to log changes
        self._deferred: Fault | None = None  # a fault found outside the loop, latched after its next block
        self._disagreed = False  # the last read-back disagreed with what was commanded
        #: the daemon installs this: the command socket's counts (handled, rejected, malformed_dropped)
        self.command_stats: Callable[[], dict[str, int]] | None = None

    # ------------------------------------------------------------- lifecycle
    @property
    def fault(self) -> Fault | None:
        return self.latch.fault

    @property
    def last_vent(self) -> tuple[Fault, float] | None:
        """The latched fault and the sample time its safe state was commanded."""
        return None if self.latch.fault is None else (self.latch.fault, self.latch.vent_t)

    @property
    def virtual(self) -> bool:
        return self.backend.source.virtual

    async def start(self, connect_in_background: bool = False) -> None:
        """Set up the devices, then run the sample loop. ``connect_in_background`` (the
        daemon): devices that cannot be reached yet do not stop the start; the loop
        retries with back-off, ``status`` says ``connecting`` meanwhile and commands that
        need the cell are refused. Without it (jobs such as a task run) that fails here."""
        if not connect_in_background:
            await self._connect()
        self._task = asyncio.create_task(self._loop(), name="fluidsense-sample-loop")

    async def _connect(self) -> None:
        await self.backend.setup()
        if self.backend.arm is not None:
            self.backend.arm.use_clock(self.clock)
        if self.backend.regulator is not None:
            self.backend.regulator.set_limits(self.profile.limits.min_pa, self.profile.limits.max_pa)
        await self.latch.command_safe_state(self.now)
        self.connected, self.connecting = True, None

    async def _connect_until_up(self) -> None:
        """Connect, retrying with back-off while the devices are not there (a robot still
        booting, a cable not yet in). A bad setting (ConfigError) does not go away by
        retrying: it ends the loop, and the daemon exits 2."""
        reconnect = getattr(self.cfg.driver, "reconnect", None)
        delay, longest = (reconnect.first_s, reconnect.max_s) if reconnect is not None else (0.5, 10.0)
        attempts = 0
        while not self._stopping:
            attempts += 1
            self.connecting = {"attempts": attempts, "error": (self.connecting or {}).get("error"),
                               "retry_in_s": None}  # an attempt in progress
            try:
                await self._connect()
            except (LinkLostError, DeviceTimeoutError, OSError) as exc:
                if self.connecting is None or self.connecting["error"] != str(exc):
                    log.warning("connecting to %s: %s; retrying", self.backend.name, exc)
                self.connecting = {"attempts": attempts, "error": str(exc), "retry_in_s": delay}
                await asyncio.sleep(delay)  # pacing the attempts (wall time), no control decision
                delay = min(2 * delay, longest)
                continue
            log.info("connected to %s after %d attempt(s)", self.backend.name, attempts)
            return
        raise asyncio.CancelledError  # stopping while connecting (a cancel an attempt swallowed)

    async def stop(self) -> None:
        """Vent, stop the loop, close the devices. Safe to call twice."""
        self._stopping = True
        if self._cancel_task():
            try:
                await self._task_job
            except (asyncio.CancelledError, Exception):  # noqa: BLE001 - stopping anyway
                pass
        if self.sequencer.busy:
            cmds = self.sequencer.abort(self.now, "shutdown")
            self._publish_transitions()
            await self._apply_guarded(cmds)
        if self._recorder is not None:  # report the interrupted cycle rather than drop it
            self._finish_cycle()
        for task in (self._task, self._readback, self._kick):
            if task is None:
                continue
            task.cancel()
            try:
                await task
            except (asyncio.CancelledError, Exception):  # noqa: BLE001 - a loop that died is reported by its owner
                pass
        self._task = self._readback = self._kick = None
        self._fail_waiters(CommandError("controller stopped"))
        await self.backend.stop(self.now)
        self._flush_pressure()
        for sink in self.sinks:
            try:
                sink.flush(self.now)
                sink.close()
            except Exception as exc:  # noqa: BLE001 - closing the others matters more
                log.error("closing sink %s: %s", type(sink).__name__, exc)

    async def __aenter__(self) -> Controller:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    async def wait_shutdown_command(self) -> None:
        """Returns when a shutdown command arrives."""
        await self._shutdown.wait()

    @property
    def loop_task(self) -> asyncio.Task[None]:
        """The sample loop: it never ends by itself; if it does, that is a bug."""
        if self._task is None:
            raise CommandError("controller is not running")
        return self._task

    # ------------------------------------------------------------ public API
    async def run_cycle(self, *, p0_kpa: float | None = None, label: str | None = None,
                        store_reference: bool = False) -> CycleResult:
        """Run one actuation cycle and return its result."""
        fut = await self.start_cycle(p0_kpa=p0_kpa, label=label, store_reference=store_reference)
        return await fut

    async def start_cycle(self, *, p0_kpa: float | None = None, label: str | None = None,
                    store_reference: bool = False, hold: bool = False) -> asyncio.Future[CycleResult]:
        """Start a cycle; the returned future resolves with its result.

        With ``hold`` the actuator stays inflated after the measurement windows until
        ``release()`` (a gripper carrying what it measured); ``measured()`` gives the
        features as soon as the last window has closed.
        """
        self._check_running()
        if self.fault is not None:
            raise FaultError(f"in FAULT ({self.fault.kind}: {self.fault.detail}); send reset")
        if self.sequencer.busy:
            raise SequenceError(f"busy: cycle {self.sequencer.cycle_id} is in {self.sequencer.state.value}")
        p0 = self.profile.sequence.p0_kpa if p0_kpa is None else p0_kpa
        lim, margin = self.profile.limits, self.profile.p0_margin_kpa
        if not lim.min_kpa <= p0 <= lim.max_kpa:
            raise SafetyError(f"p0 {p0} kPa outside the profile's limits [{lim.min_kpa}, {lim.max_kpa}] kPa")
        if self.profile.sequence.method != "flow_control" and not lim.min_kpa + margin <= p0 <= lim.max_kpa - margin:
            raise SafetyError(f"p0 {p0} kPa within {margin:.2f} kPa of the profile's limits [{lim.min_kpa}, "
                              f"{lim.max_kpa}] kPa: its readings would cross the limit and fault the cycle")
        if self.backend.watchdog is not None:
            await self.backend.watchdog.ensure_running()
        cmds = self.sequencer.start(self.now, p0 * KPA, hold=hold)
        self._cycle_opts = {"label": label, "store_reference": store_reference}
        self._hold = hold
        self._measured = asyncio.get_running_loop().create_future()
        self._recorder = Recorder()
        self._cycle_future = asyncio.get_running_loop().create_future()
        self._to_sinks("cycle_start", {"cycle_id": self.sequencer.cycle_id, "p0_pa": self.sequencer.p0_pa,
                                       "label": label, "store_reference": store_reference, "hold": hold})
        self._publish_transitions()
        await self._apply_guarded(cmds)
        self._demand.set()
        return self._cycle_future

    async def measured(self) -> CycleResult:
        """Features of the running (held) cycle once its last window has closed."""
        if self._measured is None:
            raise SequenceError("no cycle is running")
        return await self._measured

    async def release(self) -> CycleResult:
        """End a held cycle: vent, and return its final result."""
        fut = self._cycle_future
        if fut is None or not self.sequencer.busy:
            raise SequenceError("no cycle is running")
        cmds = self.sequencer.release(self.now)
        self._publish_transitions()
        await self._apply_guarded(cmds)
        self._demand.set()
        return await fut

    async def wait_after_open(self, seconds: float) -> None:
        """Wait until ``seconds`` after the running cycle's actuation valve opened."""
        while self.sequencer.busy and self.sequencer.t_open is None:
            await self.wait(self.profile.sequence.charge_s / 4)
        if self.sequencer.t_open is None:
            raise SequenceError("the cycle ended before its valve opened")
        remaining = self.sequencer.t_open + seconds - self.now
        if remaining > 0:
            await self.wait(remaining)

    async def move_l(self, pose, speed: float, acc: float) -> None:
        """Move the arm's tool in a straight line; returns on arrival (sample time)."""
        if self.backend.arm is None:
            raise NotSupportedError(f"backend {self.backend.name!r} has no arm")
        if self.fault is not None:
            raise FaultError(f"in FAULT ({self.fault.kind}); send reset")
        await self.backend.arm.move_l(pose, speed, acc, self.now)

    async def set_world(self, world: Any) -> None:
        if self.backend.scene is None:
            raise NotSupportedError(f"backend {self.backend.name!r} cannot lay out a work cell")
        await self.backend.scene.set_world(world, self.now)

    async def wait(self, seconds: float) -> None:
        """Wait ``seconds`` of sample time."""
        self._check_running()
        fut: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._waiters.append((self.now + seconds, fut))
        self._demand.set()
        await fut

    async def set_scene(self, scene: Any) -> None:
        if self.backend.scene is None:
            raise NotSupportedError(f"backend {self.backend.name!r} cannot place objects")
        await self.backend.scene.set_scene(scene, self.now)

    async def abort(self, reason: str = "operator") -> bool:
        """Abort the running cycle (vent). Returns False when nothing was running."""
        if not self.sequencer.busy:
            return False
        cmds = self.sequencer.abort(self.now, reason)
        self._publish_transitions()
        await self._apply_guarded(cmds)
        return True

    def reset(self) -> None:
        """Clear a latched fault. Refused (FaultError) until the device has confirmed the
        safe state: after a lost link, only once it is back and reads vented."""
        self.latch.clear()
        # the overrun baseline forms again from the next blocks: a loop still catching up
        # on the stall it was reset for is not a second overrun (it once latched one)
        self._wall_lag0 = None
        self.sequencer.reset(self.now)
        self._publish_transitions()

    def _start_task(self, file: str, order_mm: list[float] | None) -> dict[str, Any]:
        if self.task_runner is None:
            raise NotSupportedError("this daemon runs no tasks")
        if self._task_job is not None and not self._task_job.done():
            raise SequenceError(f"busy: task {self._task_name} is running")
        if self.sequencer.busy:
            raise SequenceError(f"busy: cycle {self.sequencer.cycle_id} is in {self.sequencer.state.value}")

        work = self.task_runner(file, order_mm)  # raises here for a bad file: an error reply

        async def job() -> None:
            try:
                await work
            except asyncio.CancelledError:
                self.emit("task", {"task": file, "event": "aborted"})
                raise
            except FluidsenseError as exc:  # the task could not go on: reported; the daemon goes on
                log.error("task %s failed: %s", file, exc)
                if self.sequencer.busy:
                    await self.abort(f"task failed: {exc}")
            except Exception as exc:  # noqa: BLE001 - a bug in a task: vent, say why
                log.exception("task %s failed", file)
                await self._enter_fault(Fault(FaultKind.INTERNAL, None, self.now,
                                              f"task {file}: {type(exc).__name__}: {exc}"))

        self._task_name = file
        self._task_job = asyncio.get_running_loop().create_task(job(), name=f"task {file}")
        return {"task": file, "started": True}

    def _cancel_task(self) -> bool:
        if self._task_job is None or self._task_job.done():
            return False
        self._task_job.cancel()
        return True

    def status(self) -> dict[str, Any]:
        last = self.results[-1].to_dict() if self.results else None
        return {
            "state": self.sequencer.state.value if self.connected else "connecting", "connecting": self.connecting,
            "cycle_id": self.sequencer.cycle_id,
            "t_s": self.now, "virtual": self.virtual, "backend": self.backend.name,
            "profile": self.profile.name,
            "fault": None if self.fault is None else {"kind": self.fault.kind, "detail": self.fault.detail,
                                                      "t_s": self.fault.t},
            "valves": self.backend.valves.reported, "valves_age_s": self.backend.valves.age_s(),
            "valves_commanded": self.backend.valves.state, "vented": vented_word(self.latch.vented()),
            "references_kpa": sorted(self.references),
            "samples": self.samples, "missed": self.missed, "last_cycle": last,
            "task": None if self._task_job is None else {"file": self._task_name, "running": not self._task_job.done()},
            "commands": None if self.command_stats is None else self.command_stats(),
            "publisher": self.pub.stats,
            # a source that keeps link counts (the serial driver: frames lost and corrupt, resets, clock drift)
            "source_link": getattr(self.backend.source, "link_stats", lambda: None)(),
        }

    async def handle_command(self, cmd: Any) -> dict[str, Any]:
        """Dispatch a validated command-socket request. A refused request is an error
        reply; anything else that raises is a bug: the cell is vented (internal fault)
        and the reply says so."""
        try:
            return await self._dispatch(cmd)
        except FluidsenseError:
            raise
        except Exception as exc:  # noqa: BLE001
            log.exception("command %s failed", getattr(cmd, "cmd", "?"))
            await self._enter_fault(Fault(FaultKind.INTERNAL, None, self.now,
                                          f"{type(exc).__name__} handling {getattr(cmd, 'cmd', '?')!r}: {exc}"))
            raise CommandError(f"internal error: {type(exc).__name__}: {exc}; the cell was put in its safe state "
                               "(send reset to go on)") from exc

    async def _dispatch(self, cmd: Any) -> dict[str, Any]:
        if isinstance(cmd, StatusCmd):
            return self.status()
        if not self.connected and not isinstance(cmd, (ShutdownCmd, AbortCmd)):
            error = (self.connecting or {}).get("error") or "first attempt under way"
            raise CommandError(f"not connected to {self.backend.name} yet ({error}); the daemon keeps trying: "
                               "wait for status to leave 'connecting'")
        if isinstance(cmd, CycleCmd):
            fut = await self.start_cycle(p0_kpa=cmd.p0_kpa, label=cmd.label, store_reference=cmd.store_reference)
            fut.add_done_callback(lambda f: f.exception() if not f.cancelled() else None)
            return {"cycle_id": self.sequencer.cycle_id}
        if isinstance(cmd, AbortCmd):
            stopped_task = self._cancel_task()
            return {"aborted": await self.abort(cmd.reason) or stopped_task}
        if isinstance(cmd, TaskCmd):
            return self._start_task(cmd.file, cmd.order_mm)
        if isinstance(cmd, ResetCmd):
            self.reset()
            return {"state": self.sequencer.state.value}
        if isinstance(cmd, SceneCmd):
            await self.set_scene(cmd.scene)
            return {"scene": cmd.scene.model_dump()}
        if isinstance(cmd, ShutdownCmd):
            self._shutdown.set()
            return {"shutting_down": True}
        raise CommandError(f"unhandled command {cmd!r}")  # pragma: no cover

    # -------------------------------------------------------------- the loop
    def _check_running(self) -> None:
        if self._task is None or self._task.done():
            raise CommandError("controller is not running")

    @property
    def loop_running(self) -> bool:
        return self._task is not None and not self._task.done()

    @property
    def idle(self) -> bool:
        """Virtual time with nothing waiting on samples: the loop is parked and sample time
        stands still by design. Parked while something waits would be a lost wake-up."""
        return self._parked and not self._has_demand()

    def _has_demand(self) -> bool:
        """In virtual time samples are only worth producing while something waits on them.
        A held cycle whose measurement is done waits on the task, not on samples."""
        if self._waiters:
            return True
        if self.sequencer.busy:
            return not (self.sequencer.state == State.HOLD and self._hold and self._measured is not None
                        and self._measured.done())
        return False

    async def _loop(self) -> None:
        """Pull blocks for ever. A source that fails or goes silent faults the cell (vent)
        and the loop keeps trying: the daemon outlives its devices. Anything else that
        raises while a block is handled (a bug, a sink, a device) trips the latch as an
        internal fault and the loop goes on with the next block, in the safe state."""
        if not self.connected:
            await self._connect_until_up()
        failures = 0
        while True:
            if self.virtual and not self._has_demand():
                self._demand.clear()
                self._parked = True
                try:
                    await self._demand.wait()
                finally:
                    self._parked = False
                continue
            try:
                block = await self._read()
            except asyncio.CancelledError:
                raise
            except Exception as exc:  # noqa: BLE001 - every device failure is a fault, none ends the loop
                failures += 1
                self.loop_ticks += 1
                await self._enter_fault(self._read_fault(exc))
                self._fail_waiters(FaultError(f"no samples: {exc}"))
                # pace the retries (the driver reconnects); wall time, but no control decision
                await asyncio.sleep(min(0.05 * 2 ** min(failures, 5), 1.0) if not self.virtual else 0)
                continue
            failures = 0
            t0 = time.perf_counter()
            try:
                await self._on_block(block)
            except asyncio.CancelledError:
                raise
            except Exception as exc:  # noqa: BLE001 - a bug must vent, not end the loop
                log.exception("the sample loop failed on block %d", block.seq)
                await self._enter_fault(Fault(FaultKind.INTERNAL, None, self.now,
                                              f"{type(exc).__name__} in the sample loop: {exc}"))
            self._proc_s.append(time.perf_counter() - t0)
            self.loop_ticks += 1
            if not self.virtual:
                # a loop that is always behind its source never reaches an await that
                # suspends: without this, signals and commands would wait for ever
                await asyncio.sleep(0)

    async def _read(self) -> SampleBlock:
        if self.virtual:
            return await self.backend.source.read_block()
        # asyncio.timeout, not wait_for: Python 3.11's wait_for returns the result when a
        # cancel arrives just as the read completes (a block already due, as while catching
        # up after a stall), and the swallowed cancel left stop() waiting for ever
        async with asyncio.timeout(self.cfg.supervision.no_data_s):
            return await self.backend.source.read_block()

    def _read_fault(self, exc: Exception) -> Fault:
        if isinstance(exc, (asyncio.TimeoutError, DeviceTimeoutError)):
            return Fault(FaultKind.NO_DATA, None, self.now, f"no samples for {self.cfg.supervision.no_data_s} s")
        if isinstance(exc, LinkLostError):
            return Fault(FaultKind.LINK_LOST, None, self.now, str(exc))
        if self.fault is None:
            log.error("sample source failed: %s", exc, exc_info=exc)
        return Fault(FaultKind.DRIVER, None, self.now, f"{type(exc).__name__}: {exc}")

    def _overrun(self, block: SampleBlock) -> Fault | None:
        """Real time only: how far the loop is behind its samples."""
        if self.virtual:
            return None
        # against the host clock through the source's origin: a device whose clock drifts
        # (a serial device's crystal) moves its origin, which is not the loop falling behind
        origin = self.backend.source.clock_origin_s
        lag = asyncio.get_running_loop().time() - block.t_end - (origin or 0.0)
        if self._wall_lag0 is None or lag < self._wall_lag0:
            self._wall_lag0 = lag
            return None
        behind = lag - self._wall_lag0
        if behind > self.cfg.supervision.overrun_s:
            return Fault(FaultKind.OVERRUN, None, block.t_end, f"the loop is {behind:.3f} s behind its samples")
        return None

    async def _on_block(self, block: SampleBlock) -> None:
        self.now = block.t_end
        self.samples += len(block)
        self.blocks += 1
        self.missed += block.missed
        self.late += block.late
        arm = self.backend.arm
        fault = self.supervisor.check(block, holding=self._holding(),
                                      arm_stopped=arm is not None and arm.protective_stopped) or self._overrun(block)
        if self._recorder is not None:
            self._recorder.add(block)
        if fault is not None and self.fault is None:
            await self._enter_fault(fault)
        cmds = self.sequencer.on_time(self.now)
        if cmds:
            await self._apply_guarded(cmds)
        self._background_io()
        self._publish_transitions()
        if self._measured is not None and not self._measured.done() and self._measurement_due():
            self._measured.set_result(self._analyse(final=False))
        if self.sequencer.state == State.IDLE and self._recorder is not None:
            self._finish_cycle()
        self._batch_pressure(block)
        for sink in list(self.sinks):
            try:
                sink.on_block(block)
            except Exception as exc:  # noqa: BLE001
                self._drop_sink(sink, exc)
        self._release_waiters()
        if self.now >= self._next_heartbeat:
            self._heartbeat()
        await self._latch_deferred()

    async def _latch_deferred(self) -> None:
        deferred, self._deferred = self._deferred, None
        if deferred is not None and self.fault is None:
            await self._enter_fault(deferred)

    async def _apply(self, cmds: list[Command]) -> None:
        for cmd in cmds:
            if isinstance(cmd, ValveCmd):
                await self.backend.valves.set(cmd.valve, cmd.open, self.now)
            elif isinstance(cmd, SetpointCmd):
                if self.backend.regulator is None:
                    raise NotSupportedError("this cell has no pressure regulator")
                await self.backend.regulator.set_setpoint(cmd.pressure_pa, self.now)
            elif isinstance(cmd, FlowProfileCmd):
                if self.backend.flow is None:
                    raise NotSupportedError("this cell has no flow controller")
                if cmd.times:
                    await self.backend.flow.set_profile(cmd.times, cmd.flows, self.now)
                else:
                    await self.backend.flow.stop_flow(self.now)
            self._to_sinks("command", _command_dict(cmd))

    async def _apply_guarded(self, cmds: list[Command]) -> None:
        """Apply commands; a device that does not carry one out faults the cell."""
        try:
            await self._apply(cmds)
        except Exception as exc:  # noqa: BLE001
            log.error("command failed: %s", exc)
            await self._enter_fault(Fault(FaultKind.COMMAND, None, self.now, str(exc)))

    async def _enter_fault(self, fault: Fault) -> None:
        """Every fault goes through here: the latch commands and confirms the safe state;
        the cycle ends with what it measured; whoever waits on samples gets the fault."""
        if self.fault is not None:  # the first cause stands
            log.debug("%s while %s is latched: %s", fault.kind, self.fault.kind, fault.detail)
            return
        self.sequencer.fault(self.now, f"fault: {fault.kind}")
        event = await self.latch.trip(fault, self.now)
        self.emit("fault", event)
        self._vented_seen = self.latch.vented()
        self._publish_transitions()
        if self._recorder is not None:
            self._finish_cycle()
        self._fail_waiters(FaultError(f"{fault.kind}: {fault.detail}"))

    def _background_io(self) -> None:
        """Started from the loop, run beside it: the valve outputs read back once per
        heartbeat period (status and ``vented`` say what the device reports), and the box
        watchdog kicked four times per timeout. Both only while the loop makes progress: a
        stalled loop stops the box watchdog's heartbeat, which is the point."""
        dog = self.backend.watchdog
        if dog is not None and self.now >= self._next_kick and (self._kick is None or self._kick.done()):
            self._next_kick = self.now + dog.timeout_s / 4
            self._kick = asyncio.create_task(self._guarded_io(dog.kick(), "kicking the box watchdog"))
        if self.backend.valves.reports_outputs and (self._readback is None or self._readback.done()) \
                and self.now >= self._next_heartbeat:
            self._readback = asyncio.create_task(self._read_outputs())

    async def _read_outputs(self) -> None:
        wrong = await self._guarded_io(self.backend.valves.disagreement(), "reading the valve outputs back")
        # twice in a row: one read can meet a write still on its way to a UR box's outputs
        if wrong and self._disagreed and self.fault is None:
            commanded = self.backend.valves.state
            self._defer_fault(f"the device reports {', '.join(f'{v} {_word(o)}' for v, o in wrong.items())}; "
                              f"commanded {', '.join(f'{v} {_word(commanded[v])}' for v in wrong)}",
                              FaultKind.COMMAND)
        self._disagreed = bool(wrong)
        vented = self.latch.vented()
        if self.fault is not None and vented != self._vented_seen:
            self._vented_seen = vented
            self.emit("log", {"level": "INFO" if vented else "WARNING",
                              "message": f"{self.fault.kind} fault: vented {vented_word(vented)} as the device reports",
                              "vented": vented_word(vented), "outputs": self.backend.valves.reported})

    async def _guarded_io(self, work: Awaitable[Any], what: str) -> Any:
        try:
            async with asyncio.timeout(max(1.0, self.cfg.publisher.heartbeat_s)):
                return await work
        except asyncio.CancelledError:
            raise
        except Exception as exc:  # noqa: BLE001 - the outputs are then unknown; the source faults a lost link
            log.debug("%s failed: %s", what, exc)
            return None

    def _holding(self) -> bool:
        """Inflated, measured, waiting: where a leak shows as a steady decay."""
        return self.sequencer.state == State.HOLD and self._measured is not None and self._measured.done()

    def _measurement_due(self) -> bool:
        seq = self.sequencer
        if seq.t_open is None:
            return seq.aborted is not None or not seq.busy
        last = max(w.end_s for w in self.profile.sequence.windows)
        return self.now >= seq.t_open + last or seq.aborted is not None or not seq.busy

    def _analyse(self, final: bool) -> CycleResult:
        rec, seq = self._recorder, self.sequencer
        t, values = rec.arrays()
        store = self._cycle_opts.get("store_reference", False)
        ref = None if store else self.references.get(_reference_key(seq.p0_pa))
        try:
            return analyse(seq.cycle_id, seq.p0_pa, seq.t_start, seq.t_open, (seq.t_end or self.now) if final else None,
                           t, values, rec.channels, self.profile.sequence, ref, aborted=seq.aborted,
                           label=self._cycle_opts.get("label"), missed=rec.missed)
        except ValueError as exc:  # too few samples for a window: report, do not crash
            return CycleResult(seq.cycle_id, seq.p0_pa, seq.t_start, seq.t_open, self.now,
                               aborted=f"analysis failed: {exc}", missed=rec.missed)

    def _finish_cycle(self) -> None:
        seq = self.sequencer
        store = self._cycle_opts.get("store_reference", False)
        key = _reference_key(seq.p0_pa)
        result = self._analyse(final=True)
        self._recorder = None
        if self._measured is not None and not self._measured.done():
            self._measured.set_result(result)
        if store and result.ok:
            self.references[key] = make_reference(result)
            result.is_reference = True
        # the caller gets the trace; the history keeps features only (a trace is ~0.6 MB)
        self.results.append(replace(result, trace=None))
        self.emit("cycle", result.to_dict())
        fut, self._cycle_future = self._cycle_future, None
        if fut is not None and not fut.done():
            fut.set_result(result)

    def add_sink(self, sink: Sink) -> None:
        self.sinks.append(sink)

    def emit(self, topic: str, payload: dict[str, Any]) -> None:
        """Publish an event and hand it to every sink. Never raises: a publisher or sink
        that fails is an internal fault, latched by the loop after the block (emit runs
        inside the fault path too, where raising would lose the fault)."""
        try:
            self.pub.send(topic, self.now, payload)
        except Exception as exc:  # noqa: BLE001
            log.exception("publishing %s failed", topic)
            self._defer_fault(f"publishing {topic!r} failed: {type(exc).__name__}: {exc}")
        self._to_sinks(topic, payload)

    def _to_sinks(self, topic: str, payload: dict[str, Any]) -> None:
        for sink in list(self.sinks):
            try:
                sink.on_event(topic, self.now, payload)
            except Exception as exc:  # noqa: BLE001 - dropped, and a fault: what it kept is incomplete
                self._drop_sink(sink, exc)

    def _drop_sink(self, sink: Sink, exc: Exception) -> None:
        """A sink that reports a failure it knows (a full disk stops a recording) is dropped
        and control goes on; anything else it raises is a bug: dropped and a fault."""
        self.sinks.remove(sink)
        if isinstance(exc, FluidsenseError):
            log.error("sink %s dropped: %s", type(sink).__name__, exc)
            return
        log.error("sink %s failed and was dropped: %s", type(sink).__name__, exc, exc_info=exc)
        self._defer_fault(f"sink {type(sink).__name__} failed: {type(exc).__name__}: {exc}")

    def _defer_fault(self, detail: str, kind: FaultKind = FaultKind.INTERNAL) -> None:
        """A fault found outside the loop's flow (sync code, background I/O): latched by
        the loop after its next block."""
        if self._deferred is None:
            self._deferred = Fault(kind, None, self.now, detail)
        self._demand.set()  # virtual time: the loop must run to latch it

    def _publish_transitions(self) -> None:
        for tr in self.sequencer.drain_transitions():
            self.emit("state", transition_dict(tr))

    def _batch_pressure(self, block: SampleBlock) -> None:
        if self._batch_start is None:
            self._batch_start = float(block.t[0])
        self._batch.append(block)
        # n samples cover n sample periods: a batch as long as one block is one block.
        # Half a period of slack: a polled source stamps each read when it happens, and a
        # first sample a few ns later than the last one must not hold the batch for a
        # second block (measured: the oldest sample 20 ms old instead of 10 on Modbus)
        period = 1.0 / self.backend.source.rate_hz
        covered = self.now + period - self._batch_start
        if covered + 0.5 * period >= self.cfg.publisher.pressure_batch_s:
            self._flush_pressure()

    def _flush_pressure(self) -> None:
        if not self._batch:
            return
        t = np.concatenate([b.t for b in self._batch])
        channels = self._batch[0].channels
        v = np.vstack([b.values for b in self._batch]) / np.array([_EDGE_SCALE[_unit(c)] for c in channels])
        origin = self.backend.source.clock_origin_s
        self.pub.send("pressure", self.now, {
            "t0_s": float(t[0]), "rate_hz": self.backend.source.rate_hz, "n": len(t),
            "clock_origin_s": origin, "sent_s": None if origin is None else time.monotonic(),
            "channels": list(channels), "units": [_unit(c) for c in channels],
            "times_s": t.tolist(), "values": np.round(v, 5).T.tolist()})
        self._batch, self._batch_start = [], None

    def _release_waiters(self) -> None:
        if not self._waiters:
            return
        keep = []
        for t_target, fut in self._waiters:
            if self.now >= t_target - 1e-12:
                if not fut.done():
                    fut.set_result(None)
            else:
                keep.append((t_target, fut))
        self._waiters = keep

    def _fail_waiters(self, exc: Exception) -> None:
        for _, fut in self._waiters:
            if not fut.done():
                fut.set_exception(exc)
        self._waiters = []
        for fut in (self._cycle_future, self._measured):
            if fut is not None and not fut.done():
                fut.set_exception(exc)

    def _heartbeat(self) -> None:
        period = self.cfg.publisher.heartbeat_s
        self._next_heartbeat = (np.floor(self.now / period) + 1) * period
        proc = np.array(self._proc_s) * 1e6 if self._proc_s else np.zeros(1)
        self.emit("heartbeat", {
            "state": self.sequencer.state.value, "cycle_id": self.sequencer.cycle_id,
            "fault": None if self.fault is None else self.fault.kind,
            "samples": self.samples, "blocks": self.blocks, "missed": self.missed, "late": self.late,
            "rate_hz": self.backend.source.rate_hz, "virtual": self.virtual,
            "block_proc_us": {"p50": float(np.percentile(proc, 50)), "p99": float(np.percentile(proc, 99)),
                              "max": float(proc.max())},
            "pub_dropped": self.pub.dropped, "uptime_s": time.monotonic() - self._started_wall,
        })
        self._proc_s.clear()
