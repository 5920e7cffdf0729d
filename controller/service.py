"""The controller: the parts below, wired; the interface tasks and requests use.

    sampling/loop.py     pulls blocks from the backend's source (the only reader)
    safety/supervisor.py checks every block: limits, NaN, rail, stuck, leak, stop
    safety/latch.py      a fault: vent, confirm with the device, publish, latch
    cycles/runner.py     the sequencer's plans on the devices, the cycle's trace, features
    telemetry/fanout.py  events to the publisher and the recording
    sampling/clock.py    sample time: waits released by samples

Each part is handed the others through a named port (path.py: SampleTime, Events,
Faults, Stream, EventPublisher; the loop's BlockPipeline is this controller), never a bare
callable; path.py follows one sample from the driver's block to the published
``pressure`` event.

The command socket's requests (requests/) are wired onto this interface by the daemon;
the controller knows nothing of them. Tasks get its task port (ports.py TaskPort).

Per block (``on_block``): clock (waits released) -> cycle trace -> supervisor (-> latch)
-> cycle runner -> outputs watch -> telemetry -> block watchers -> heartbeat -> deferred
faults.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import asynccontextmanager
from functools import cached_property
from pathlib import Path
from typing import Any

from fluidsense.common.errors import CommandError, FaultError, LinkLostError, SequenceError
from fluidsense.common.faults import Fault, FaultKind
from fluidsense.common.samples import SampleBlock
from fluidsense.common.units import KPA
from fluidsense.drivers.backend import Backend

from .cell import ArmAccess, SceneAccess
from .config import CellConfig
from .cycles.analysis import CycleResult, Reference
from .cycles.kept import ReferenceKeeper, identity
from .cycles.analysis import reference_key
from .cycles.runner import CycleRunner
from .path import BlockWatcher, EventPublisher
from .ports import TaskPort
from .safety.latch import SafetyLatch, vented_word
from .safety.outputs import OutputWatch
from .safety.supervisor import Supervisor
from .safety.ventpath import vent_path
from .sampling.clock import SampleClock
from .sampling.loop import SampleLoop
from .telemetry.fanout import Sink, Telemetry
from .telemetry.publisher import NullPublisher

log = logging.getLogger(__name__)


class Controller:
    """The parts wired (each is handed the others through a path.py port: the clock as
    SampleTime, the latch as Faults, the telemetry as Events, the source as Stream, the
    publisher as EventPublisher), and the sample loop's BlockPipeline itself."""

    def __init__(self, cfg: CellConfig, backend: Backend, publisher: EventPublisher | None = None):
        self.cfg, self.profile, self.backend = cfg, cfg.profile, backend
        self.clock = SampleClock()
        self.latch = SafetyLatch(backend, self.clock.demand)
        self.telemetry = Telemetry(publisher or NullPublisher(), cfg.publisher, clock=self.clock, stream=backend.source,
                                   faults=self.latch)
        self.cycles = CycleRunner(self.profile, backend, clock=self.clock, events=self.telemetry, faults=self.latch,
                                  freeze_s=cfg.supervision.freeze_s)
        self.supervisor = Supervisor(self.profile, cfg.supervision)
        self.outputs = OutputWatch(backend, self.latch, self.telemetry, cfg.publisher.heartbeat_s)
        self.loop = SampleLoop(cfg, backend, pipeline=self, clock=self.clock)
        self.arm = ArmAccess(backend, self.latch, self.clock)
        self.scene = SceneAccess(backend, self.clock)
        #: what follows the running cycle block by block beside the telemetry (the gripper's
        #: watch: requests/wiring.py), called after the block's telemetry (``watch``)
        self.watchers: list[BlockWatcher] = []
        self.latch.before_vent.append(self.cycles.on_fault)
        self.latch.after_vent.append(self._vented)
        self._task: asyncio.Task[None] | None = None
        #: the free-air references with their age; on disk once the daemon asks (``keep_references``)
        self.keeper = ReferenceKeeper(None, identity(cfg))
        self.cycles.on_reference.append(self._reference_stored)
        self._keeping: asyncio.Future[None] | None = None
        self._keep_pool: ThreadPoolExecutor | None = None
        #: what vents the gripper on a dead link (static: from the config)
        self.vent_path = vent_path(cfg)
        #: the sample loop's scheduling as the daemon asked for it (``use_realtime``); a
        #: library caller (a test, a bench) keeps its own
        self.realtime: dict[str, Any] = {
            "sched_fifo": "not_needed" if backend.source.virtual else "not_requested", "priority": None,
            "detail": "virtual time" if backend.source.virtual else "not asked for by this process"}

    # ------------------------------------------------------------------ lifecycle
    async def start(self, connect_in_background: bool = False) -> None:
        """Set the devices up, then run the sample loop. ``connect_in_background`` (the
        daemon): devices that cannot be reached yet do not stop the start; the loop
        retries, ``status`` says ``connecting`` meanwhile and commands that need the cell
        are refused. Without it (jobs such as a task run) that fails here."""
        if not connect_in_background:
            try:
                await self.loop.connect_now()
            except (LinkLostError, OSError) as exc:  # DeviceTimeoutError included: not there, not bad input
                raise self.cfg.driver.unreachable(exc) from exc
        self._task = asyncio.create_task(self.loop.run(), name="fluidsense-sample-loop")

    async def set_up(self) -> None:
        """The devices set up for sampling (the sample loop connects through this: path.py
        BlockPipeline), and commanded to their safe state."""
        await self.backend.setup()
        if self.backend.arm is not None:
            self.backend.arm.use_clock(self.clock)
        if self.backend.regulator is not None:
            self.backend.regulator.set_limits(self.profile.limits.min_pa, self.profile.limits.max_pa)
        await self.latch.command_safe_state(self.now)

    async def stop(self) -> None:
        """Vent, stop the loop (cancelled and awaited), close the devices and the sinks.
        Safe to call twice."""
        self.loop.stopping = True
        if self.cycles.busy:
            await self.cycles.abort("shutdown")
        if self.cycles.tracing:  # report the interrupted cycle rather than drop it
            self.cycles.finish()
        if self._task is not None:
            self._task.cancel()
            try:
                await self._task
            except (asyncio.CancelledError, Exception):  # noqa: BLE001 - a loop that died is reported by its owner
                pass
            self._task = None
        await self.outputs.stop()
        if self._keep_pool is not None:  # a reference being written is finished, not cut off
            if self._keeping is not None:
                await asyncio.wait([self._keeping])
            self._keep_pool.shutdown(wait=True)
        self.clock.fail(CommandError("controller stopped"))
        self.cycles.fail(CommandError("controller stopped"))
        await self.backend.stop(self.now)
        self.telemetry.close()

    async def __aenter__(self) -> Controller:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    @property
    def loop_task(self) -> asyncio.Task[None]:
        """The sample loop: it never ends by itself; if it does, that is a bug."""
        if self._task is None:
            raise CommandError("controller is not running")
        return self._task

    @property
    def running(self) -> bool:
        return self._task is not None and not self._task.done()

    def keep_references(self, path: Path | None) -> None:
        """Keep free-air references in ``path`` (None: not at all) and take back the ones
        there that still belong to this cell (controller/cycles/kept.py). Before ``start``."""
        self.keeper = ReferenceKeeper(path, self.keeper.ident)
        for key, kept in self.keeper.load().items():
            self.cycles.references[reference_key(kept.p0_kpa * KPA)] = kept.reference
        if path is not None:
            # one writer thread: files are written in the order the references came
            self._keep_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="fluidsense-references")

    def _reference_stored(self, p0_pa: float, key: float, ref: Reference) -> None:
        data = self.keeper.add(p0_pa, key, ref)
        if data is None or self._keep_pool is None:
            return
        # written off the sample loop (a forced write takes milliseconds); said on the log topic once on disk
        fut = asyncio.get_running_loop().run_in_executor(self._keep_pool, self.keeper.write, data)
        self._keeping = fut
        fut.add_done_callback(lambda f, p0=p0_pa / KPA: self._reference_kept(f, p0))

    def _reference_kept(self, fut: asyncio.Future[None], p0_kpa: float) -> None:
        exc = None if fut.cancelled() else fut.exception()
        if exc is None and not fut.cancelled():
            self.keeper.error = None
            self.telemetry.emit("log", {"level": "INFO", "message": f"free-air reference at {p0_kpa:g} kPa kept in "
                                        f"{self.keeper.path}"})
            return
        self.keeper.error = f"{self.keeper.path}: not written: {exc or 'cancelled'}"
        log.error("free-air reference at %g kPa: %s (it holds until the daemon stops)", p0_kpa, self.keeper.error)
        self.telemetry.emit("log", {"level": "ERROR", "message": f"free-air reference at {p0_kpa:g} kPa not kept: "
                                    f"{self.keeper.error}"})

    def use_realtime(self, result: dict[str, Any], priority: int | None) -> None:
        """What ``set_fifo`` answered for the sample loop's thread (the daemon asks before
        it starts): ``granted``, ``refused`` (with why) or ``not_requested``, in ``status``
        and the heartbeat."""
        word = "granted" if result["applied"] else "refused" if result["requested"] else "not_requested"
        self.realtime = {"sched_fifo": word, "priority": priority, "detail": result["detail"]}

    # ------------------------------------------------------------------ the interface
    @property
    def now(self) -> float:
        return self.clock.now

    @property
    def fault(self) -> Fault | None:
        return self.latch.fault

    @property
    def virtual(self) -> bool:
        return self.backend.source.virtual

    @property
    def connected(self) -> bool:
        return self.loop.connected

    @property
    def connecting(self) -> dict[str, Any] | None:
        return self.loop.connecting

    async def run_cycle(self, *, p0_kpa: float | None = None, label: str | None = None,
                        store_reference: bool = False) -> CycleResult:
        """Run one actuation cycle and return its result."""
        return await (await self.start_cycle(p0_kpa=p0_kpa, label=label, store_reference=store_reference))

    async def start_cycle(self, *, p0_kpa: float | None = None, label: str | None = None,
                          store_reference: bool = False, hold: bool = False) -> asyncio.Future[CycleResult]:
        """Start a cycle; the future resolves with its result. ``hold``: the actuator stays
        inflated after its windows until ``release()`` (a gripper carrying what it measured)."""
        self._check_running()
        if self.fault is not None:
            raise FaultError(f"in FAULT ({self.fault.kind}: {self.fault.detail}); send reset")
        if self.backend.watchdog is not None:
            await self.backend.watchdog.ensure_running()
        fut = await self.cycles.start(p0_kpa, label, store_reference, hold)
        self.clock.demand.set()
        return fut

    async def measured(self) -> CycleResult:
        """Features of the running (held) cycle once its last window has closed."""
        return await self.cycles.measured()

    async def release(self) -> CycleResult:
        """End a held cycle: vent, and return its final result."""
        return await (await self.let_go())

    async def let_go(self) -> asyncio.Future[CycleResult]:
        """End a held cycle without waiting for it: vent; the future resolves with its
        final result."""
        self.clock.demand.set()
        return await self.cycles.let_go()

    def reference(self, p0_pa: float) -> Reference | None:
        """The free-air reference at this P0, if one was measured."""
        return self.cycles.references.get(reference_key(p0_pa))

    async def abort(self, reason: str = "operator") -> bool:
        """Abort the running cycle (vent). False when nothing was running."""
        return await self.cycles.abort(reason)

    def reset(self) -> None:
        """Clear a latched fault; refused (FaultError) until the device has confirmed the
        safe state (after a lost link: once it is back and reads vented)."""
        self.latch.clear()
        self.loop.reset_lag()
        self.cycles.reset()

    async def wait(self, seconds: float) -> None:
        """Wait ``seconds`` of sample time."""
        self._check_running()
        await self.clock.wait(seconds)

    async def wait_after_open(self, seconds: float) -> None:
        """Wait until ``seconds`` after the running cycle's actuation valve opened."""
        seq = self.cycles.sequencer
        while seq.busy and seq.t_open is None:
            await self.wait(self.profile.sequence.charge_s / 4)
        if seq.t_open is None:
            raise SequenceError("the cycle ended before its valve opened")
        if seq.t_open + seconds > self.now:
            await self.wait(seq.t_open + seconds - self.now)

    @cached_property
    def task_port(self) -> TaskPort:
        """What a task may ask of this controller (ports.py): tasks/ are handed this, never
        the controller."""
        arm, scene = self.arm, self.scene
        return TaskPort(profile=self.profile, now=lambda: self.now, run_cycle=self.run_cycle,
                        start_cycle=self.start_cycle, measured=self.measured, release=self.release,
                        wait_after_open=self.wait_after_open, reference=self.reference, fault=lambda: self.fault,
                        emit=self.emit, simulated=scene.available, place=scene.place, lay_out=scene.lay_out,
                        truth=scene.truth, move_l=arm.move_l, tcp_pose=lambda: arm.tcp_pose)

    def add_sink(self, sink: Sink) -> None:
        self.telemetry.sinks.append(sink)

    def watch(self, watcher: BlockWatcher) -> None:
        """Hand every block to ``watcher`` after its telemetry (path.py BlockWatcher)."""
        self.watchers.append(watcher)

    def emit(self, topic: str, payload: dict[str, Any]) -> None:
        """Publish an event (a task's progress) and hand it to the sinks."""
        self.telemetry.emit(topic, payload)

    async def fail(self, detail: str) -> None:
        """A bug outside the sample loop (a request handler, a task job): vent and latch an
        internal fault that says where."""
        await self.latch.trip(Fault(FaultKind.INTERNAL, None, self.now, detail), self.now)

    def status(self) -> dict[str, Any]:
        """The controller's state, read from its parts (the command socket's ``status``
        adds the requests' own)."""
        seq, valves, fault = self.cycles.sequencer, self.backend.valves, self.fault
        return {
            "state": seq.state.value if self.connected else "connecting", "connecting": self.connecting,
            "cycle_id": seq.cycle_id, "t_s": self.now, "virtual": self.virtual, "backend": self.backend.name,
            "profile": self.profile.name,
            "fault": None if fault is None else {"kind": fault.kind, "detail": fault.detail, "t_s": fault.t},
            "valves": valves.reported, "valves_age_s": valves.age_s(), "valves_commanded": valves.state,
            "vented": vented_word(self.latch.vented()), "references_kpa": sorted(self.cycles.references),
            "samples": self.loop.samples, "missed": self.loop.missed,
            "last_cycle": self.cycles.results[-1].to_dict() if self.cycles.results else None,
            "publisher": self.telemetry.pub.stats,
            "sinks": [{**sink.stats, "state": "running"} for sink in self.telemetry.sinks if hasattr(sink, "stats")]
            + self.telemetry.failed_sinks,
            # a source that keeps link counts (the serial driver: frames lost and corrupt, resets, clock drift)
            "source_link": getattr(self.backend.source, "link_stats", lambda: None)(),
            "vent_path": self.vent_path, "realtime": self.realtime, "reference_store": self.keeper.status(),
        }

    def heartbeat(self) -> dict[str, Any]:
        """The heartbeat's fields: the few a watcher needs every second."""
        seq, loop = self.cycles.sequencer, self.loop
        return {"state": seq.state.value, "cycle_id": seq.cycle_id,
                "fault": None if self.fault is None else self.fault.kind, "samples": loop.samples,
                "blocks": loop.blocks, "missed": loop.missed, "late": loop.late,
                "rate_hz": self.backend.source.rate_hz, "virtual": self.virtual,
                "realtime": self.realtime["sched_fifo"], "vent_path": self.vent_path["by"]}

    # ------------------------------------------------------------------ the loop's side (path.py BlockPipeline)
    def _check_running(self) -> None:
        if not self.running:
            raise CommandError("controller is not running")

    @property
    def wants_samples(self) -> bool:
        """Something waits on samples: a wait on the clock, or a cycle that needs them."""
        return self.clock.waiting or self.cycles.wants_samples

    async def on_block(self, block: SampleBlock) -> None:
        """One block from the sample loop, through every part in this order (path.py)."""
        self.clock.advance(block.t_end)
        self.cycles.trace(block)
        fault = self.supervisor.check(block, holding=self.cycles.holding,
                                      arm_stopped=self.arm.protective_stopped) or self.loop.overrun(block)
        if fault is not None:
            await self.latch.trip(fault, self.now)
        await self.cycles.on_block()
        self.outputs.on_block(self.now)
        self.telemetry.on_block(block)
        self._watch(block)
        if self.telemetry.heartbeat_due():
            self.telemetry.heartbeat(self.heartbeat(), self.loop.proc_s)
        await self.latch.trip_deferred(self.now)

    def _watch(self, block: SampleBlock) -> None:
        """The block to each watcher; one that raises is a bug: it is dropped, said on the
        ``log`` topic, and an internal fault is latched after the block (as for a sink)."""
        for watcher in list(self.watchers):
            try:
                watcher.on_block(block)
            except Exception as exc:  # noqa: BLE001 - dropped, and a fault
                self.watchers.remove(watcher)
                name, reason = type(watcher).__name__, f"{type(exc).__name__}: {exc}"
                log.error("block watcher %s failed and was dropped: %s", name, reason, exc_info=exc)
                self.telemetry.emit("log", {"level": "ERROR", "message": f"{name} failed and was dropped: {reason}",
                                            "watcher": name})
                self.latch.defer(f"{name} failed: {reason}", FaultKind.INTERNAL, self.now)

    async def on_read_failure(self, fault: Fault) -> None:
        """No block: a fault, and whoever waits on samples now is told (none will come)."""
        await self.latch.trip(fault, self.now)
        self.clock.fail(FaultError(f"no samples: {fault.detail}"))

    def _vented(self, fault: Fault, event: dict[str, Any]) -> None:
        """After the latch vented (its ``after_vent``): the fault published, the outputs
        watch told, the cycle ended with what it measured, every wait on samples released."""
        self.telemetry.emit("fault", event)
        self.outputs.tripped()
        self.cycles.after_fault(fault, event)
        self.clock.fail(FaultError(f"{fault.kind}: {fault.detail}"))


@asynccontextmanager
async def open_cell(cfg: CellConfig, backend: Backend) -> AsyncIterator[TaskPort]:
    """A controller started on ``backend`` for one job, as its task port (ports.OpenCell);
    stopped (vented, the devices closed) when the job leaves it."""
    async with Controller(cfg, backend) as ctrl:
        yield ctrl.task_port
