"""What the production drivers share: links to remote equipment, and a sample source
that polls analog inputs in the sampler process and reconnects after a loss.

A backend's devices (valves, regulator, arm) talk through one or more ``Connection``s (a
Modbus client, the ur_rtde worker process). The source is the backend's heartbeat:
every block it delivers also checks every link, so a link lost while the cell is idle
still becomes a fault within one block. After a loss every read raises
``LinkLostError`` until a reconnection succeeds (drivers/reconnect.py: attempts in a task
of their own with back-off, because reopening links and starting a sampler process takes
longer than the controller waits for one block; under load, more than its 0.5 s, and
attempts cut off by that wait never succeeded). The links stay open until an attempt
starts, so that the safe state the controller writes on the loss still reaches a box whose
link is up (only the sampler died, or a stop signal to the process group reached it
first). A successful attempt restarts the sampler and reopens the links, and sample time
carries on from the first connection's origin, the gap reported as missed slots.

Each connection, the first one included, then runs the backend's ``on_connect`` steps
before any sample is delivered: the valves go to their safe positions and are read back
(a box that kept its outputs while the link was down must not stay inflated), and the
box-side watchdog is installed. A step that fails fails the connection.
"""

from __future__ import annotations

import abc
import asyncio
import dataclasses
import logging
from collections.abc import Awaitable, Callable

from fluidsense.common.errors import DeviceProtocolError, LinkLostError
from fluidsense.common.samples import SampleBlock
from fluidsense.drivers.base import SampleSource, ValveBank

from .reconnect import Reconnect, Reconnector
from .sampler.config import PollerSpec, SamplerConfig, SamplerOptions
from .sampler.source import SampledSource

log = logging.getLogger(__name__)


class Connection(abc.ABC):
    """A connection that several devices share. ``check()`` raises LinkLostError once the
    link is known to be gone; ``open()`` (re)connects."""

    name: str = "link"

    @abc.abstractmethod
    async def open(self) -> None: ...

    @abc.abstractmethod
    async def close(self) -> None: ...

    @abc.abstractmethod
    def check(self) -> None: ...


async def confirm_safe_on_connect(valves: ValveBank) -> None:
    """A connection's first act: every valve to its safe position, read back. The box kept
    its outputs while the link was down (an inflated gripper stays inflated)."""
    if await valves.confirm_safe(float("nan")) is False:
        raise LinkLostError(f"{valves.name}: the device does not report the safe positions after they were written")
    log.info("%s: safe positions written and read back", valves.name)


def sampler_config(poller: str, kwargs: dict, channels: tuple[str, ...], rate_hz: float, block_size: int,
                   options: SamplerOptions, start_timeout_s: float) -> SamplerConfig:
    return SamplerConfig(poller=PollerSpec(factory=poller, kwargs=kwargs), channels=channels, rate_hz=rate_hz,
                         block_size=block_size, start_timeout_s=start_timeout_s, **options.model_dump())


class PolledCellSource(SampleSource):
    def __init__(self, name: str, cfg: SamplerConfig, links: list[Connection], reconnect: Reconnect):
        super().__init__(name)
        self.cfg = cfg
        self.links = links
        self.reconnect = reconnect
        self.rate_hz = cfg.rate_hz
        self.channels = tuple(cfg.channels)
        self.sampler: SampledSource | None = None
        self._origin: float | None = None  # CLOCK_MONOTONIC of sample time 0
        self._seq = 0
        self._t_last: float | None = None
        self._reconnector = Reconnector(name, reconnect, self._reconnect)
        #: run after the links open, before the sampler starts, at every connection
        self.on_connect: list[Callable[[], Awaitable[None]]] = []

    @property
    def clock_origin_s(self) -> float | None:
        return self._origin

    async def _setup(self) -> None:
        await self._connect()

    async def _connect(self) -> None:
        opened: list[Connection] = []
        try:
            # asyncio.timeout, not wait_for: Python 3.11's wait_for can swallow the cancel of
            # a daemon that stops while an attempt ends, and the attempts then go on for ever
            for link in self.links:
                async with asyncio.timeout(self.reconnect.connect_timeout_s):
                    await link.open()
                opened.append(link)
            for step in self.on_connect:
                async with asyncio.timeout(self.reconnect.connect_timeout_s):
                    await step()
            sampler = SampledSource(self.cfg, name=f"{self.name}-sampler")
            await sampler.setup()
        except BaseException as exc:
            for link in reversed(opened):
                await link.close()
            if isinstance(exc, asyncio.TimeoutError):
                raise LinkLostError(f"{self.name}: no connection within {self.reconnect.connect_timeout_s:g} s") \
                    from exc
            raise
        self.sampler = sampler
        if self._origin is None:
            self._origin = sampler.t0_monotonic_s

    async def _read_block(self) -> SampleBlock:
        if self._reconnector.lost is not None:
            await self._reconnector.attempt()
        try:
            block = await self.sampler.read_block()
            for link in self.links:
                link.check()
        except DeviceProtocolError as exc:
            # the device said what cannot be true: this fault (driver) names the field, the
            # reads after it say the link is lost while it reconnects (as the serial link does)
            await self._lose(LinkLostError(f"{self.name}: {exc}; reconnecting"))
            raise
        except LinkLostError as exc:
            await self._lose(exc)
            raise
        return self._rebase(block)

    def _rebase(self, block: SampleBlock) -> SampleBlock:
        """One sample clock across reconnections: times from the first origin, the gap
        while disconnected reported as missed slots."""
        t = block.t + (self.sampler.t0_monotonic_s - self._origin)
        missed = block.missed
        if self._t_last is not None:
            missed = max(missed, int(round((t[0] - self._t_last) * self.rate_hz)) - 1)
        self._t_last = float(t[-1])
        self._seq += 1
        return dataclasses.replace(block, seq=self._seq, t=t, missed=missed)

    async def _lose(self, exc: LinkLostError) -> None:
        """Only the sampler goes now: a link that is still up (the sampler died, or a stop
        signal reached it first) carries the safe state the controller writes next. What
        is left is closed when the reconnection starts."""
        self._reconnector.lose(exc)
        sampler, self.sampler = self.sampler, None
        if sampler is not None:
            try:
                await sampler.stop()
            except Exception as err:  # noqa: BLE001 - lost already; the reconnection starts afresh
                log.error("%s: stopping the sampler: %s", self.name, err)

    async def _reconnect(self) -> None:
        await self._close_all()
        await self._connect()

    async def _close_all(self) -> None:
        """The sampler and every link at once: each waits on its own peer (ur_rtde's
        disconnects take about 0.5 s each), and none needs another closed first (the valves
        were made safe before)."""
        sampler, self.sampler = self.sampler, None
        results = await asyncio.gather(*([sampler.stop()] if sampler is not None else []),
                                       *(link.close() for link in reversed(self.links)), return_exceptions=True)
        for name, res in zip([*(["sampler"] if sampler is not None else []), *(lk.name for lk in reversed(self.links))],
                             results):
            if isinstance(res, Exception):
                log.error("%s: closing %s: %s", self.name, name, res)
            elif isinstance(res, BaseException):  # cancelled while closing: the others are closed
                raise res

    async def _stop(self) -> None:
        await self._reconnector.cancel()
        await self._close_all()
