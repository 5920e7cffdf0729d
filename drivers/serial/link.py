"""One open serial port to the streamer (firmware/README.md): frames in, commands out.

Reading never blocks the event loop: either a reader thread waits on the port and hands
the loop whole sample blocks (``reader: thread``), or the loop reads the port itself when
it is readable (``reader: loop``, add_reader); the frame handling is the same code.

What can go wrong on the wire, and what it becomes (docs/drivers.md):
- a corrupt frame (CRC, COBS) or a lost one (a gap in the device's frame ``seq``) costs
  its own sample: the slot is reported missed. More than ``damaged_limit`` of them within
  one second make the link unusable: DriverError (a ``driver`` fault);
- the device reset (a frame without our session: its power-on state, outputs low, ticks
  from 0): DeviceResetError (a ``driver`` fault), and the source reconnects;
- the device vented by its heartbeat watchdog: DriverError (a ``driver`` fault);
- a frame whose contents cannot be true (a channel count, tick, rate or sequence the
  device could not have: stream.py): DeviceProtocolError (a ``driver`` fault), once, and
  the source reconnects;
- the port failed or closed (unplugged): LinkLostError (``link_lost``), reconnection;
- no valid frame for ``silence_s``: LinkLostError (``link_lost``), reconnection.
"""

from __future__ import annotations

import asyncio
import logging
import os
import random
import select
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import serial
from fluidsense.common.errors import (
    DeviceProtocolError,
    DeviceTimeoutError,
    DriverError,
    LinkLostError,
)
from fluidsense.common.samples import SampleBlock

from . import protocol as p
from .clock import Timeline
from .config import SerialDriverConfig
from .session import DamageWindow
from .stream import Blocks, DeviceResetError, SessionGuard

__all__ = ["DeviceResetError", "SerialLink"]

log = logging.getLogger(__name__)


class SerialLink:
    def __init__(self, cfg: SerialDriverConfig, timeline: Timeline, channels: tuple[str, ...],
                 adc_mask: int, order: np.ndarray, gain: np.ndarray, offset: np.ndarray):
        self.cfg = cfg
        self.name = f"serial {cfg.port}"
        self.timeline = timeline
        self.channels, self.adc_mask = channels, adc_mask
        self._blocks = Blocks(timeline, channels, order, gain, offset, cfg.block_size)
        self.queue: asyncio.Queue[SampleBlock | BaseException] = asyncio.Queue()
        self.info: p.Info | None = None
        self.session: int | None = None
        self.delivering = False
        self.outputs: int | None = None  # as the newest sample frame reports them
        self.outputs_tick = -1
        self.vented = False
        self.last_frame = time.monotonic()
        self.stats = dict.fromkeys(("bytes", "frames", "samples", "corrupt_frames", "lost_frames", "stale_frames",
                                    "device_tx_dropped", "adc_overruns", "commands", "retries", "acks",
                                    "implausible_frames"), 0)
        self._ser: serial.Serial | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._lost: LinkLostError | None = None
        self._dead = False
        self._splitter = p.Splitter()
        self._acks: dict[int, asyncio.Future[p.Ack]] = {}
        self._tick_waiters: list[tuple[int, asyncio.Future[int]]] = []
        self._cmd_seq = random.randrange(1 << 16)
        self._cmd_lock = asyncio.Lock()
        self._started = False  # START acknowledged: frames of another session now mean a reset
        self._dev_seq: int | None = None
        self._raw_tick: int | None = None
        self._tick = -1  # unwrapped tick of the session
        self._guard: SessionGuard | None = None  # from START's acknowledgement
        self._lost_since_sample = 0  # frames missing (seq) since the last sample frame
        self._damage = DamageWindow(cfg.damaged_limit)
        self._thread: threading.Thread | None = None
        self._wake: tuple[int, int] | None = None

    # ------------------------------------------------------------ opening and closing
    async def open(self) -> None:
        self._loop = asyncio.get_running_loop()
        try:
            self._ser = await self._loop.run_in_executor(None, self._open_port)
        except (serial.SerialException, OSError) as exc:
            raise LinkLostError(f"{self.name}: {exc}") from exc
        fd = self._ser.fileno()
        if self.cfg.reader == "thread":
            self._wake = os.pipe()
            self._thread = threading.Thread(target=self._run, args=(fd,), name="serial-reader", daemon=True)
            self._thread.start()
        else:
            self._loop.add_reader(fd, self._readable, fd)

    def _open_port(self) -> serial.Serial:
        ser = serial.Serial(port=self.cfg.port, baudrate=self.cfg.baudrate, timeout=0, write_timeout=1.0,
                            exclusive=True)
        ser.reset_input_buffer()  # whatever a previous session left
        return ser

    async def close(self) -> None:
        self._dead = True
        if self._thread is not None:
            os.write(self._wake[1], b"x")
            await asyncio.get_running_loop().run_in_executor(None, self._thread.join, 2.0)
            for fd in self._wake:
                os.close(fd)
            self._thread = self._wake = None
        elif self._ser is not None and self._loop is not None:
            self._loop.remove_reader(self._ser.fileno())
        if self._ser is not None:
            self._ser.close()
            self._ser = None
        self._lost = self._lost or LinkLostError(f"{self.name}: closed")
        for fut in [*self._acks.values(), *(f for _, f in self._tick_waiters)]:
            if not fut.done():
                fut.set_exception(self._lost)
        self._acks.clear()
        self._tick_waiters.clear()

    def check(self) -> None:
        if self._lost is not None:
            raise self._lost

    # ------------------------------------------------------------ the session
    async def command(self, kind: int, args: bytes = b"", tries: int | None = None,
                      timeout_s: float | None = None) -> p.Ack:
        """Send a command and wait for its acknowledgement, sending it again after each
        timeout; one command at a time (a retry overtaking a newer command would undo it)."""
        tries = self.cfg.retries + 1 if tries is None else tries
        timeout_s = self.cfg.ack_timeout_s if timeout_s is None else timeout_s
        name = p.COMMAND_NAMES[kind]
        async with self._cmd_lock:
            self.check()
            self._cmd_seq = (self._cmd_seq + 1) & 0xFFFF
            seq, data = self._cmd_seq, p.command(kind, self._cmd_seq, args)
            self.stats["commands"] += 1
            for attempt in range(tries):
                fut = self._loop.create_future()
                self._acks[seq] = fut
                self.stats["retries"] += attempt > 0
                self._write(data)
                try:
                    async with asyncio.timeout(timeout_s):
                        ack = await fut
                except TimeoutError:
                    # the ack came in time but the loop, late itself, ran the timer before
                    # the reader's hand-over (its callback was queued first): not a retry
                    if not fut.done() or fut.cancelled():
                        continue
                    ack = fut.result()
                finally:
                    self._acks.pop(seq, None)
                if ack.status != p.OK:
                    raise DriverError(f"{self.name}: {name} refused: {p.STATUS_NAMES.get(ack.status, ack.status)}")
                return ack
        self.check()
        raise DeviceTimeoutError(f"{self.name}: {name} not acknowledged after {tries} tries ({timeout_s:g} s each)")

    def _write(self, data: bytes) -> None:
        try:
            self._ser.write(data)
        except (serial.SerialException, OSError) as exc:
            self._lose(LinkLostError(f"{self.name}: write failed: {exc}"), tell=False)
            raise self._lost from exc

    async def outputs_after(self, tick: int, timeout_s: float) -> int:
        """The outputs as a sample frame taken after device tick ``tick`` reports them (a
        read-back that cannot precede the write it checks)."""
        self.check()
        if self.outputs_tick > tick:
            return self.outputs
        fut = self._loop.create_future()
        self._tick_waiters.append((tick, fut))
        try:
            async with asyncio.timeout(timeout_s):
                return await fut
        except TimeoutError as exc:
            raise DeviceTimeoutError(f"{self.name}: no sample frame for {timeout_s:g} s to read the outputs") \
                from exc

    async def next_block(self) -> SampleBlock:
        while True:
            if self._lost is not None and self.queue.empty():
                raise self._lost
            try:
                async with asyncio.timeout(self.cfg.silence_s):
                    item = await self.queue.get()
            except TimeoutError:
                quiet = time.monotonic() - self.last_frame
                if quiet >= self.cfg.silence_s:
                    self._lose(LinkLostError(f"{self.name}: no valid frame for {quiet:.2f} s (silent link: device "
                                             f"hung, cable, or wrong baud rate)"), tell=False)
                    raise self._lost from None
                continue
            if isinstance(item, BaseException):
                raise item
            return item

    def unwrap(self, raw_tick: int) -> int:
        """A device tick near the newest one, unwrapped as the samples' ticks are."""
        if self._raw_tick is None or raw_tick < 0:
            return raw_tick
        delta = (raw_tick - self._raw_tick) & 0xFFFFFFFF
        return self._tick + (delta - (1 << 32) if delta >= 1 << 31 else delta)

    # ------------------------------------------------------------ reading (thread or loop)
    def _run(self, fd: int) -> None:
        wake = self._wake[0]
        while not self._dead:
            ready = select.select([fd, wake], [], [], 1.0)[0]
            if wake in ready:
                return
            if fd in ready and not self._read(fd):
                return

    def _readable(self, fd: int) -> None:
        if not self._read(fd):
            self._loop.remove_reader(fd)

    def _read(self, fd: int) -> bool:
        try:
            data = os.read(fd, 65536)
        except BlockingIOError:
            return True
        except OSError as exc:
            self._post(self._lose, LinkLostError(f"{self.name}: read failed: {exc} (device unplugged?)"))
            return False
        if not data:
            self._post(self._lose, LinkLostError(f"{self.name}: the port closed (device unplugged?)"))
            return False
        arrival = time.monotonic()
        self.stats["bytes"] += len(data)
        before = self._splitter.corrupt
        for payload in self._splitter.feed(data):
            try:
                self._frame(p.parse(payload), arrival)
            except p.ProtocolError as exc:
                self._splitter.corrupt += 1
                log.debug("%s: %s", self.name, exc)
        self.stats["corrupt_frames"] += self._splitter.corrupt - before
        return True

    def _post(self, fn: Callable[..., Any], *args: Any) -> None:
        """Run ``fn`` in the event loop: at once from the loop's reader, queued from the thread."""
        if self._thread is not None and threading.current_thread() is self._thread:
            self._loop.call_soon_threadsafe(fn, *args)
        else:
            fn(*args)

    def _lose(self, exc: LinkLostError, tell: bool = True) -> None:
        """The link is gone: every command fails from now on; ``tell`` queues the error for
        the next read."""
        if self._lost is None:
            self._lost = exc
            if tell:
                self.queue.put_nowait(exc)
        self._dead = True

    def _fail(self, exc: BaseException) -> None:
        self.queue.put_nowait(exc)

    def _frame(self, f: p.Sample | p.Ack | p.Info, arrival: float) -> None:
        if self._dead:
            return
        self.last_frame = arrival
        self.stats["frames"] += 1
        if isinstance(f, p.Info):
            self.info = f
        if self._started:
            if f.session != self.session:
                if f.session == 0:
                    self._reset(f)
                else:
                    self.stats["stale_frames"] += 1
                return
            gap = (f.seq - self._dev_seq - 1) & 0xFFFF  # every frame type counts in seq
            self._dev_seq = f.seq
            if gap:
                self.stats["lost_frames"] += gap
                self._lost_since_sample += gap
                if not isinstance(f, p.Sample):  # a sample frame's gap is damage once the guard believes it
                    self._damaged(gap, arrival)
        if isinstance(f, p.Ack):
            if f.command == p.START and f.status == p.OK and f.session == self.session and not self._started:
                self._started, self._dev_seq = True, f.seq
                self._guard = SessionGuard(self.cfg, len(self.channels), arrival)
            self.stats["acks"] += 1  # a retry's repeat is acknowledged again: one per command sent
            self._post(self._resolve, f)
        elif isinstance(f, p.Sample):
            if self._started:
                self._sample(f, arrival, gap)
            else:
                self.stats["stale_frames"] += 1  # still streaming for an earlier session

    def _reset(self, f: p.Sample | p.Ack | p.Info) -> None:
        cause = f"{f.reset_cause}" if isinstance(f, p.Info) else "a frame without the session"
        self._drop(DeviceResetError(f"{self.name}: the device reset ({cause}): it restarted with its outputs at "
                                    "their power-on levels and its ticks from 0"), "the device reset")

    def _drop(self, exc: DriverError, why: str) -> None:
        """The session is over (the device reset, or said what cannot be true): ``exc`` is
        the one fault it makes; every later frame is ignored, every read and command after
        it says the link is lost, and the source reconnects."""
        self._dead = True  # at once, in the reader: no later frame of the session is looked at
        self._post(self._end_session, exc, LinkLostError(f"{self.name}: {why}; reconnecting"))

    def _sample(self, f: p.Sample, arrival: float, gap: int) -> None:
        if self._raw_tick is None:
            tick = f.tick
        else:
            tick = self.unwrap(f.tick)
            if tick <= self._tick:
                self._reset(f)
                return
        lost, self._lost_since_sample = self._lost_since_sample, 0
        lie = self._guard.check(f, tick, arrival, lost, self.stats["commands"] + self.stats["retries"])
        if lie is not None:
            self.stats["implausible_frames"] += 1
            self._drop(DeviceProtocolError(f"{self.name}: {lie}", lie.field), f"the device said what cannot be "
                       f"true ({lie.field})")
            return
        self._raw_tick, self._tick = f.tick, tick
        if gap:
            self._damaged(gap, arrival)
        k = self.timeline.slot(tick, arrival)
        self.outputs, self.outputs_tick = f.outputs, tick
        vented = bool(f.flags & p.F_VENTED)
        if vented and not self.vented:
            self._post(self._fail, DriverError(
                f"{self.name}: the device vented by itself: no heartbeat for {self.cfg.watchdog.timeout_s:g} s"))
        self.vented = vented
        self.stats["device_tx_dropped"] += bool(f.flags & p.F_TX_DROPPED)
        self.stats["adc_overruns"] += bool(f.flags & p.F_ADC_LATE)
        self.stats["samples"] += 1
        if self._tick_waiters:
            self._post(self._wake_waiters, tick, f.outputs)
        if not self.delivering:
            return
        block = self._blocks.add(k, f)
        if block is not None:
            self._post(self.queue.put_nowait, block)

    def _damaged(self, n: int, arrival: float) -> None:
        total = self._damage.add(n, arrival)
        if total is not None:
            self._post(self._fail, DriverError(
                f"{self.name}: {total} frames lost or corrupt within one second (limit {self.cfg.damaged_limit}): "
                "check the cable, its shield and ground, and the baud rate"))

    # ------------------------------------------------------------ in the loop
    def _end_session(self, exc: DriverError, lost: LinkLostError) -> None:
        """In the loop, in this order: the fault queued before the link says it is lost (a read
        that saw the loss first would reconnect and the fault would never be told), then a
        command or read-back waiting on the session fails now, not at its timeout."""
        self.queue.put_nowait(exc)
        self._lost = self._lost or lost
        for fut in [*self._acks.values(), *(f for _, f in self._tick_waiters)]:
            if not fut.done():
                fut.set_exception(self._lost)
        self._tick_waiters.clear()

    def _resolve(self, ack: p.Ack) -> None:
        fut = self._acks.get(ack.command_seq)
        if fut is not None and not fut.done():
            fut.set_result(ack)

    def _wake_waiters(self, tick: int, outputs: int) -> None:
        keep = []
        for want, fut in self._tick_waiters:
            if tick > want:
                if not fut.done():
                    fut.set_result(outputs)
            else:
                keep.append((want, fut))
        self._tick_waiters = keep
