"""The sample loop: the only reader of the backend's source.

It connects (the daemon's start: retrying with back-off while the devices are not there),
then pulls blocks for ever and hands each to the controller's pipeline (its ``pipeline``,
controller/path.py BlockPipeline: service.Controller.on_block). A read that
fails or times out becomes a fault and the loop keeps trying: the daemon outlives its
devices. Anything the pipeline raises is an internal fault, and the loop goes on with
the next block, in the safe state. In real time it measures how far it is behind its
samples (overrun) and yields after every block (a loop that is always behind would
otherwise never let a signal or a command in). In virtual time it pulls only while
something waits on samples; otherwise sample time stands still.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import deque
from typing import Any

from fluidsense.common.errors import DeviceTimeoutError, LinkLostError
from fluidsense.common.faults import Fault, FaultKind
from fluidsense.common.samples import SampleBlock
from fluidsense.drivers.backend import Backend
from fluidsense.drivers.base import SampleSource

from ..config import CellConfig
from ..path import BlockPipeline
from .clock import SampleClock

log = logging.getLogger(__name__)


class SampleLoop:
    def __init__(self, cfg: CellConfig, backend: Backend, *, pipeline: BlockPipeline, clock: SampleClock):
        """``pipeline``: where each block goes, and a failed read (it sets the devices up
        too); ``clock``: sample time, and its ``demand``, set when something starts waiting
        on samples (virtual time: the loop parks until then)."""
        self.cfg, self.backend = cfg, backend
        self.pipeline, self.clock = pipeline, clock
        self.connected = False
        self.connecting: dict[str, Any] | None = None  # while not connected: attempts, last error
        self.parked = False  # virtual time, nothing waits on samples
        self.stopping = False
        self.running = False  # inside run(): the systemd watchdog's "alive"
        self.ticks = 0  # iterations completed (a block, or a failed read handled): the systemd watchdog
        self.samples = self.blocks = self.missed = self.late = 0
        self.proc_s: deque[float] = deque(maxlen=2000)
        self._wall_lag0: float | None = None  # wall clock minus sample time of the least late block
        # when the block before was taken (perf_counter): an overrun says how long the loop
        # was away, which tells a slow block (proc_s) from a loop that did not run
        self._taken_s: float | None = None
        self._away_s = 0.0

    @property
    def source(self) -> SampleSource:
        """The backend's source, where every block comes from (drivers/base.py)."""
        return self.backend.source

    @property
    def virtual(self) -> bool:
        return self.source.virtual

    @property
    def idle(self) -> bool:
        """Parked with nothing waiting on samples: sample time stands still by design."""
        return self.parked and not self.pipeline.wants_samples

    def reset_lag(self) -> None:
        """The overrun baseline forms again from the next blocks: a loop still catching up
        on the stall it was reset for is not a second overrun (it once latched one)."""
        self._wall_lag0 = None

    async def run(self) -> None:
        self.running = True
        try:
            await self._run()
        finally:
            self.running = False

    async def _run(self) -> None:
        if not self.connected:
            await self._connect_until_up()
        failures = 0
        while True:
            if self.virtual and not self.pipeline.wants_samples:
                self.clock.demand.clear()
                self.parked = True
                try:
                    await self.clock.demand.wait()
                finally:
                    self.parked = False
                continue
            try:
                block = await self._read()
            except asyncio.CancelledError:
                raise
            except Exception as exc:  # noqa: BLE001 - every device failure is a fault, none ends the loop
                failures += 1
                self.ticks += 1
                await self.pipeline.on_read_failure(self._read_fault(exc))
                # pace the retries (the driver reconnects); wall time, but no control decision
                await asyncio.sleep(min(0.05 * 2 ** min(failures, 5), 1.0) if not self.virtual else 0)
                continue
            failures = 0
            t0 = time.perf_counter()
            self._away_s = t0 - self._taken_s if self._taken_s is not None else 0.0
            self._taken_s = t0
            self.samples += len(block)
            self.blocks += 1
            self.missed += block.missed
            self.late += block.late
            try:
                await self.pipeline.on_block(block)
            except asyncio.CancelledError:
                raise
            except Exception as exc:  # noqa: BLE001 - a bug must vent, not end the loop
                log.exception("the sample loop failed on block %d", block.seq)
                await self.pipeline.on_read_failure(Fault(FaultKind.INTERNAL, None, self.clock.now,
                                                          f"{type(exc).__name__} in the sample loop: {exc}"))
            self.proc_s.append(time.perf_counter() - t0)
            self.ticks += 1
            if not self.virtual:
                await asyncio.sleep(0)

    async def connect_now(self) -> None:
        """Set the devices up at once (jobs: a device that is not there fails the start)."""
        await self.pipeline.set_up()
        self.connected, self.connecting = True, None

    async def _connect_until_up(self) -> None:
        """Connect, retrying with back-off while the devices are not there (a robot still
        booting, a cable not yet in). A bad setting (ConfigError) does not go away by
        retrying: it ends the loop, and the daemon exits 2."""
        reconnect = getattr(self.cfg.driver, "reconnect", None)
        delay, longest = (reconnect.first_s, reconnect.max_s) if reconnect is not None else (0.5, 10.0)
        attempts = 0
        while not self.stopping:
            attempts += 1
            self.connecting = {"attempts": attempts, "error": (self.connecting or {}).get("error"),
                               "retry_in_s": None}  # an attempt in progress
            try:
                await self.connect_now()
            except (LinkLostError, DeviceTimeoutError, OSError) as exc:
                if self.connecting["error"] != str(exc):
                    log.warning("connecting to %s: %s; retrying", self.backend.name, exc)
                self.connecting = {"attempts": attempts, "error": str(exc), "retry_in_s": delay}
                await asyncio.sleep(delay)  # pacing the attempts (wall time), no control decision
                delay = min(2 * delay, longest)
                continue
            log.info("connected to %s after %d attempt(s)", self.backend.name, attempts)
            return
        raise asyncio.CancelledError  # stopping while connecting (a cancel an attempt swallowed)

    async def _read(self) -> SampleBlock:
        if self.virtual:
            return await self.source.read_block()
        # asyncio.timeout, not wait_for: Python 3.11's wait_for returns the result when a
        # cancel arrives just as the read completes (a block already due, as while catching
        # up after a stall), and the swallowed cancel left stop() waiting for ever
        async with asyncio.timeout(self.cfg.supervision.no_data_s):
            return await self.source.read_block()

    def _read_fault(self, exc: Exception) -> Fault:
        now = self.clock.now
        if isinstance(exc, (asyncio.TimeoutError, DeviceTimeoutError)):
            return Fault(FaultKind.NO_DATA, None, now, f"no samples for {self.cfg.supervision.no_data_s} s")
        if isinstance(exc, LinkLostError):
            return Fault(FaultKind.LINK_LOST, None, now, str(exc))
        return Fault(FaultKind.DRIVER, None, now, f"{type(exc).__name__}: {exc}")

    def overrun(self, block: SampleBlock) -> Fault | None:
        """Real time only: how far the loop is behind its samples, against its best."""
        if self.virtual:
            return None
        # against the host clock through the source's origin: a device whose clock drifts
        # (a serial device's crystal) moves its origin, which is not the loop falling behind
        origin = self.source.clock_origin_s
        lag = asyncio.get_running_loop().time() - block.t_end - (origin or 0.0)
        if self._wall_lag0 is None or lag < self._wall_lag0:
            self._wall_lag0 = lag
            return None
        behind = lag - self._wall_lag0
        if behind > self.cfg.supervision.overrun_s:
            slowest = max(self.proc_s, default=0.0)
            return Fault(FaultKind.OVERRUN, None, block.t_end,
                         f"the loop is {behind:.3f} s behind its samples ({self._away_s * 1e3:.0f} ms since it took "
                         f"the block before; the slowest block since the last heartbeat took {slowest * 1e3:.0f} ms)")
        return None
