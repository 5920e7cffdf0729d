"""A device that lies on the wire: a frame-level proxy between the firmware's pty and the
driver that rewrites chosen device -> host frames and sends them on with a valid CRC, as
a faulty or hostile device would (a firmware built for another board, a counter that
jumps, a timer at the wrong rate). Each frame is decoded with the protocol module,
changed field by field, and encoded again; frames it is not asked to change pass as they
came, byte for byte. The board behind it is the real firmware (tests/support/serial.py)."""

from __future__ import annotations

import struct
from pathlib import Path

from fluidsense.drivers.serial import protocol as p

from support.serial import Proxy

_HEAD = struct.Struct("<BBH")  # type, session, seq: every device frame starts so
_TICK = struct.Struct("<I")  # a sample's tick at offset 4; an ACK's at offset 8
RATE_FACTOR = 10


def _frames(buffer: bytearray, data: bytes) -> list[bytes]:
    """``data`` appended to ``buffer``; the whole frames in it (COBS, delimiter stripped)
    taken out, the unfinished rest left in ``buffer``."""
    buffer += data
    *frames, rest = bytes(buffer).split(b"\x00")
    buffer[:] = rest
    return frames


class Liar(Proxy):
    """``lie("counts", frames=n)``: the next n sample frames (whatever their session) carry
    one count more than the inputs wired. ``lie("tick")``: from now on, the current
    session's ticks are 10**6 ahead. ``lie("rate")``: the current session streams
    RATE_FACTOR frames for each of the device's, ticks RATE_FACTOR times as fast, ``seq``
    renumbered so that no frame is missing. The tick and rate lies end with the session
    (the driver's next START). ``swallow(n)``: the next n SET_OUTPUTS commands never reach
    the device (a USB hiccup while the valves are written). ``lie("refuse")``: the device
    refuses every SET_OUTPUTS (its ACK says "argument refused")."""

    def __init__(self, device: str, link: Path):
        self._raw = bytearray()
        self.mode: str | None = None
        self.remaining = 0
        self.lied = 0  # frames rewritten (the rate lie: frames sent in their place)
        self._session: int | None = None  # the session the tick and rate lies belong to
        self._base_tick: int | None = None
        self._seq = 0
        self._out = bytearray()
        self.swallowing = 0
        self.swallowed = 0
        super().__init__(device, link)

    def swallow(self, n: int) -> None:
        with self._lock:
            self.swallowing = n

    def _filter_out(self, data: bytes) -> bytes:
        out = bytearray()
        with self._lock:
            for raw in _frames(self._out, data):
                decoded = p.cobs_decode(raw) if raw else None
                if decoded and decoded[0] == p.SET_OUTPUTS and self.swallowing > 0:
                    self.swallowing -= 1
                    self.swallowed += 1
                    continue
                out += raw + b"\x00"
        return bytes(out)

    def lie(self, mode: str, frames: int = 0) -> None:
        with self._lock:
            self.mode, self.remaining, self._session, self._base_tick = mode, frames, None, None

    def _filter(self, data: bytes) -> bytes:
        out = bytearray()
        with self._lock:
            for raw in _frames(self._raw, data):
                out += self._rewrite(raw) if raw else b"\x00"
        return bytes(out)

    def _rewrite(self, raw: bytes) -> bytes:
        """One frame as it came (COBS, no delimiter) -> the bytes to send on, delimiters included."""
        as_came = raw + b"\x00"
        decoded = p.cobs_decode(raw)
        if self.mode is None or decoded is None or len(decoded) < 6:
            return as_came
        payload = decoded[:-2]
        if p.crc16(payload) != int.from_bytes(decoded[-2:], "little"):
            return as_came
        kind, session, seq = _HEAD.unpack_from(payload)
        if self.mode == "refuse":
            if kind != p.ACK or payload[4] != p.SET_OUTPUTS:
                return as_came
            self.lied += 1
            return p.frame(payload[:7] + bytes([p.E_ARG]) + payload[8:])
        if self.mode == "counts":
            if kind != p.SAMPLE:
                return as_came
            self.lied += 1
            self.remaining -= 1
            if self.remaining <= 0:
                self.mode = None
            return p.frame(payload + struct.pack("<H", 512))
        if self._session is None:  # the lie starts with the session streaming now
            if kind != p.SAMPLE:
                return as_came
            self._session, self._base_tick, self._seq = session, _TICK.unpack_from(payload, 4)[0], seq
        if session != self._session:
            self.mode = None  # a new session: the lie is over
            return as_came
        if self.mode == "tick":
            return self._frame_at(payload, self._tick_of(payload, kind) + 10**6, seq)
        # rate: RATE_FACTOR sample frames for each, every frame renumbered
        if kind != p.SAMPLE:
            self._seq = (self._seq + 1) & 0xFFFF
            return self._frame_at(payload, self._fast(self._tick_of(payload, kind)) + RATE_FACTOR - 1, self._seq)
        out = b""
        tick = self._fast(self._tick_of(payload, kind))
        for i in range(RATE_FACTOR):
            self._seq = (self._seq + 1) & 0xFFFF
            out += self._frame_at(payload, tick + i, self._seq)
            self.lied += 1
        return out

    def _fast(self, tick: int) -> int:
        return self._base_tick + RATE_FACTOR * (tick - self._base_tick)

    @staticmethod
    def _tick_of(payload: bytes, kind: int) -> int:
        return _TICK.unpack_from(payload, 4 if kind == p.SAMPLE else 8)[0]

    def _frame_at(self, payload: bytes, tick: int, seq: int) -> bytes:
        """``payload`` with its ``seq`` and tick replaced (an ACK without a tick keeps none)."""
        kind = payload[0]
        at = 4 if kind == p.SAMPLE else 8 if kind == p.ACK else None
        out = bytearray(payload)
        struct.pack_into("<H", out, 2, seq & 0xFFFF)
        if at is not None and _TICK.unpack_from(payload, at)[0] != p.NO_TICK:
            _TICK.pack_into(out, at, tick & 0xFFFFFFFF)
        if kind == p.SAMPLE and self.mode == "tick":
            self.lied += 1
        return p.frame(bytes(out))
