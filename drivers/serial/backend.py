"""Build the serial backend: a hardware-timed sample source that reconnects, valves and a
regulator set by acknowledged commands, the device's heartbeat watchdog.

The source is the backend's link: every device talks through its current ``SerialLink``.
After a loss (port gone, silent link, device reset) every read raises LinkLostError
while attempts to reconnect run in a task of their own, with backoff (as the UR drivers'
``PolledCellSource``). Each connection, the first one included, says HELLO, checks what
the device is, STARTs a new session, then runs the ``on_connect`` steps (every valve to
its safe position, read back from the device's frames) before any sample is delivered.
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import struct
from collections.abc import Awaitable, Callable
from typing import Any

import numpy as np
from fluidsense.common.errors import ConfigError, LinkLostError
from fluidsense.common.hardware import Hardware, RegulatedCircuit, TankCircuit
from fluidsense.common.samples import SampleBlock
from fluidsense.common.wiring import AnalogScale, RegulatorWiring

from ..backend import Backend
from ..base import BoxWatchdog, Regulator, SampleSource, ValveBank
from ..reconnect import Reconnector
from . import protocol as p
from .clock import Timeline
from .config import SerialDriverConfig, SerialValveWiring
from .link import SerialLink
from .handshake import handshake
from .stream import DeviceResetError

log = logging.getLogger(__name__)

RAW_MAX = 65535


def aout_raw(wiring: RegulatorWiring, scale: AnalogScale, pressure_pa: float) -> int:
    gain, offset = scale.raw_affine(wiring.input)
    return min(RAW_MAX, max(0, round((wiring.to_signal(pressure_pa) - offset) / gain)))


def count_scale(cfg: SerialDriverConfig, channels: tuple[str, ...]) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """(adc mask, order, gain, offset): the device sends the counts of the channels in its
    mask lowest input first; ``values[:, order]`` puts them in ``channels`` order, and
    Pa = gain * count + offset (the count's middle, through the sensor's transfer)."""
    wired = [(cfg.wiring.sensors[name].adc, name) for name in channels]
    by_adc = sorted(wired)
    order = np.array([by_adc.index(w) for w in wired])
    lsb = cfg.adc.reference_v / 2 ** cfg.adc.bits
    gain, offset = [], []
    for _, name in wired:
        g, o = cfg.wiring.sensors[name].transfer.affine()
        gain.append(lsb / g)
        offset.append((0.5 * lsb - o) / g)
    return sum(1 << a for a, _ in wired), order, np.array(gain), np.array(offset)


class SerialSource(SampleSource):
    def __init__(self, cfg: SerialDriverConfig, hw: Hardware):
        super().__init__("serial")
        self.cfg = cfg
        self.rate_hz = float(cfg.rate_hz)
        self.channels = hw.channels
        self.timeline = Timeline(cfg.rate_hz)
        self.adc_mask, self._order, self._gain, self._offset = count_scale(cfg, self.channels)
        self._start = _start_args(cfg, hw, self.adc_mask)
        self.link: SerialLink | None = None
        self.info: p.Info | None = None
        #: run after START, before the first sample is delivered, at every connection
        self.on_connect: list[Callable[[], Awaitable[None]]] = []
        self.connections = self.resets = 0
        self._totals: dict[str, int] = {}
        self._session: int | None = None
        self._seq = 0
        self._reconnector = Reconnector(self.name, cfg.reconnect, self._connect)

    @property
    def clock_origin_s(self) -> float | None:
        return self.timeline.origin

    def require_link(self) -> SerialLink:
        link = self.link
        if link is None:
            raise self._reconnector.lost or LinkLostError(f"{self.name}: not connected")
        link.check()
        return link

    def link_stats(self) -> dict[str, Any]:
        """Counts over every connection so far, the clock alignment, the device."""
        counts = dict(self._totals)
        if self.link is not None:
            for key, value in self.link.stats.items():
                counts[key] = counts.get(key, 0) + value
        return {"connections": self.connections, "resets": self.resets, **counts, **self.timeline.stats(),
                "session": self._session, "device": None if self.info is None else dataclasses.asdict(self.info)}

    async def _setup(self) -> None:
        await self._connect()

    async def _connect(self) -> None:
        link = SerialLink(self.cfg, self.timeline, self.channels, self.adc_mask, self._order, self._gain,
                          self._offset)
        timeout = self.cfg.reconnect.connect_timeout_s
        try:
            async with asyncio.timeout(timeout):
                await link.open()
                self.info = await handshake(link, self._start, self._session)
                self.link = link
                for step in self.on_connect:
                    await step()
        except BaseException as exc:
            self.link = None
            await link.close()
            if isinstance(exc, TimeoutError):
                raise LinkLostError(f"{self.name}: no connection within {timeout:g} s") from exc
            raise
        self._session = link.session
        link.delivering = True
        self.connections += 1

    async def _read_block(self) -> SampleBlock:
        if self._reconnector.lost is not None:
            await self._reconnector.attempt()
        try:
            block = await self.link.next_block()
        except DeviceResetError as exc:
            self.resets += 1
            await self._lose(LinkLostError(f"{exc}; reconnecting"))
            raise  # the reset is the fault (driver); the reads after it say link lost
        except LinkLostError as exc:
            await self._lose(exc)
            raise
        self._seq += 1
        return dataclasses.replace(block, seq=self._seq)

    async def _lose(self, exc: LinkLostError) -> None:
        self._reconnector.lose(exc)
        await self._close_link()

    async def _close_link(self) -> None:
        link, self.link = self.link, None
        if link is None:
            return
        for key, value in link.stats.items():
            self._totals[key] = self._totals.get(key, 0) + value
        # shielded: the read that found the loss runs under the sample loop's no_data_s timeout, and
        # a close cancelled while it joins the reader thread left the port open and locked, so every
        # reconnection failed ("Could not exclusively lock port")
        await asyncio.shield(link.close())

    async def _stop(self) -> None:
        await self._reconnector.cancel()
        if self.link is not None and self._reconnector.lost is None:
            try:  # outputs safe, streaming off, the device's watchdog disarmed: nothing left to guard
                await self.link.command(p.STOP, tries=2)
            except Exception as exc:  # noqa: BLE001 - closing anyway; the device's watchdog vents
                log.warning("%s: STOP not acknowledged: %s", self.name, exc)
        log.info("%s: %s", self.name, self.link_stats())
        await self._close_link()


def _start_args(cfg: SerialDriverConfig, hw: Hardware, adc_mask: int) -> Callable[[int], bytes]:
    valves, safe = cfg.wiring.valves, hw.circuit.safe_valves
    safe_levels = sum(int(valves[v].level(open_)) << valves[v].output for v, open_ in safe.items())
    used = sum(1 << w.output for w in valves.values())
    safe_aout = [0, 0]
    if cfg.wiring.regulator is not None:
        reg = cfg.wiring.regulator
        safe_aout[reg.analog_output] = aout_raw(reg, cfg.analog_out, 0.0)
    heartbeat_ms = max(10, round(cfg.watchdog.timeout_s * 1000))
    return lambda session: p.start_args(session, cfg.rate_hz, heartbeat_ms, safe_levels, used, adc_mask,
                                        tuple(safe_aout))


class SerialValves(ValveBank):
    reports_outputs = True

    def __init__(self, source: SerialSource, wiring: dict[str, SerialValveWiring], safe: dict[str, bool]):
        super().__init__("serial-valves", safe)
        self.source, self.wiring = source, wiring
        self._written: tuple[SerialLink, int] | None = None  # the last acknowledged write: its link and tick

    async def _set(self, valve: str, open: bool, t: float) -> None:
        link = self.source.require_link()
        w = self.wiring[valve]
        ack = await link.command(p.SET_OUTPUTS, bytes([1 << w.output, int(w.level(open)) << w.output]))
        self._written = (link, link.unwrap(ack.tick))

    async def _read_positions(self) -> dict[str, bool]:
        link = self.source.require_link()
        after = self._written[1] if self._written is not None and self._written[0] is link else -1
        bits = await link.outputs_after(after, timeout_s=max(0.1, 20 / self.source.rate_hz))
        return {name: bool(bits >> w.output & 1) == w.level(True) for name, w in self.wiring.items()}


class SerialRegulator(Regulator):
    def __init__(self, source: SerialSource, wiring: RegulatorWiring, scale: AnalogScale):
        super().__init__("serial-regulator")
        self.source, self.wiring, self.scale = source, wiring, scale

    async def _set_setpoint(self, pressure_pa: float, t: float) -> None:
        raw = aout_raw(self.wiring, self.scale, pressure_pa)
        await self.source.require_link().command(p.SET_AOUT, struct.pack("<BH", self.wiring.analog_output, raw))


class SerialHeartbeat(BoxWatchdog):
    """The device's own watchdog: it vents when these heartbeats stop for ``timeout_s``."""

    def __init__(self, source: SerialSource, timeout_s: float):
        super().__init__("serial-heartbeat", timeout_s)
        self.source = source

    async def _kick(self) -> None:
        await self.source.require_link().command(p.HEARTBEAT)

    async def _ensure_running(self) -> None:
        link = self.source.require_link()
        if link.vented:  # the device holds its outputs safe until re-armed
            await link.command(p.ARM)
            log.warning("%s: re-armed after the device vented by itself", self.name)


async def confirm_safe_on_connect(valves: ValveBank) -> None:
    """A connection's first act: every valve to its safe position, read back (a device
    that kept its outputs while the link was down must not stay inflated)."""
    if await valves.confirm_safe(float("nan")) is False:
        raise LinkLostError(f"{valves.name}: the device does not report the safe positions after they were written")
    log.info("%s: safe positions written and read back", valves.name)


def build(cfg: SerialDriverConfig, hw: Hardware, read_only: bool = False) -> Backend:
    if read_only:  # a session starts with the device's outputs at their safe levels: a write
        raise ConfigError("driver: the serial driver has no read-only mode (a session sets the outputs safe); "
                          "fluidsense check --actuate, or check with the daemon's own status")
    source = SerialSource(cfg, hw)
    valves = SerialValves(source, cfg.wiring.valves, hw.circuit.safe_valves)
    source.on_connect.append(lambda: confirm_safe_on_connect(valves))
    regulated = isinstance(hw.circuit, (TankCircuit, RegulatedCircuit)) and cfg.wiring.regulator is not None
    regulator = SerialRegulator(source, cfg.wiring.regulator, cfg.analog_out) if regulated else None
    scene = None
    if cfg.sim_control_port is not None:
        from fluidsense.drivers.simlink import RemoteScene  # noqa: PLC0415 - a simulated device was asked for

        scene = RemoteScene("127.0.0.1", cfg.sim_control_port)
    return Backend(name="serial", source=source, valves=valves, regulator=regulator, scene=scene,
                   watchdog=SerialHeartbeat(source, cfg.watchdog.timeout_s))
