"""The serial streamer's wire protocol, host side (firmware/README.md is the reference;
firmware/core/ the device side): COBS frames delimited by 0x00, each ending in a
CRC-16/CCITT-FALSE, every field little-endian.

Pure functions and a byte-stream splitter, no I/O: the link feeds it whatever the port
returned and gets decoded frames, damaged ones counted.
"""

from __future__ import annotations

import binascii
import struct
from dataclasses import dataclass

PROTO_VERSION = 1

# device -> host
SAMPLE, ACK, INFO = 0x01, 0x02, 0x03
# host -> device
HELLO, START, STOP, HEARTBEAT, SET_OUTPUTS, SET_AOUT, ARM = 0x10, 0x11, 0x12, 0x13, 0x14, 0x15, 0x16
COMMAND_NAMES = {HELLO: "HELLO", START: "START", STOP: "STOP", HEARTBEAT: "HEARTBEAT", SET_OUTPUTS: "SET_OUTPUTS",
                 SET_AOUT: "SET_AOUT", ARM: "ARM"}
# acknowledgement status
OK, E_LENGTH, E_UNKNOWN, E_ARG, E_NO_SESSION, E_VENTED = range(6)
STATUS_NAMES = {OK: "ok", E_LENGTH: "bad length", E_UNKNOWN: "unknown command", E_ARG: "argument refused",
                E_NO_SESSION: "no session (not started)", E_VENTED: "held safe by the heartbeat watchdog: ARM first"}
# flags of sample and ack frames
F_ARMED, F_VENTED, F_TX_DROPPED, F_ADC_LATE = 0x01, 0x02, 0x04, 0x08
RESET_CAUSES = {0: "power-on", 1: "external reset", 2: "brown-out", 3: "watchdog", 4: "software"}
NO_TICK = 0xFFFFFFFF
MAX_FRAME = 254  # decoded, CRC included: one COBS block, one byte of overhead


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE: polynomial 0x1021, initial 0xFFFF, no reflection (binascii
    implements exactly this update in C)."""
    return binascii.crc_hqx(data, 0xFFFF)


def cobs_encode(data: bytes) -> bytes:
    if len(data) > MAX_FRAME:
        raise ValueError(f"a frame holds at most {MAX_FRAME} bytes, got {len(data)}")
    out = bytearray()
    for block in data.split(b"\x00"):
        out.append(len(block) + 1)
        out += block
    return bytes(out)


def cobs_decode(data: bytes) -> bytes | None:
    """The decoded frame, or None when ``data`` is not valid COBS for a short frame."""
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        code = data[i]
        end = i + code
        if code == 0 or end > n:
            return None
        out += data[i + 1:end]
        i = end
        if i < n and code != 0xFF:  # a full block carries no zero after it
            out.append(0)
    return bytes(out)


def frame(payload: bytes) -> bytes:
    """Payload -> the bytes on the wire (CRC, COBS, delimiter)."""
    return cobs_encode(payload + struct.pack("<H", crc16(payload))) + b"\x00"


def command(kind: int, seq: int, args: bytes = b"") -> bytes:
    return frame(struct.pack("<BH", kind, seq & 0xFFFF) + args)


def start_args(session: int, rate_hz: int, heartbeat_ms: int, safe_levels: int, used_outputs: int, adc_mask: int,
               safe_aout: tuple[int, int]) -> bytes:
    return struct.pack("<BHHBBBHH", session, rate_hz, heartbeat_ms, safe_levels, used_outputs, adc_mask, *safe_aout)


@dataclass(frozen=True, slots=True)
class Sample:
    session: int
    seq: int
    tick: int
    outputs: int
    flags: int
    late_us: int
    aout: tuple[int, int]
    counts: tuple[int, ...]


@dataclass(frozen=True, slots=True)
class Ack:
    session: int
    seq: int
    command: int
    command_seq: int
    status: int
    tick: int  # the last sample tick before the command took effect; -1: none yet
    outputs: int
    flags: int


@dataclass(frozen=True, slots=True)
class Info:
    session: int
    seq: int
    version: int
    board: str
    adc_bits: int
    n_adc: int
    n_outputs: int
    n_aout: int
    max_rate_hz: int
    rate_hz: int
    reset_cause: str
    heartbeat_ms: int
    rx_errors: int


_SAMPLE_HEAD = struct.Struct("<BBHIBBBHH")
_ACK = struct.Struct("<BBHBHBIBB")
_INFO = struct.Struct("<BBHB8sBBBBHHBHH")


class ProtocolError(ValueError):
    """A frame that passed its CRC but does not parse (a firmware of another protocol)."""


def parse(payload: bytes) -> Sample | Ack | Info:
    """A CRC-checked payload (CRC removed) -> its frame."""
    kind = payload[0]
    if kind == SAMPLE:
        n = len(payload) - _SAMPLE_HEAD.size
        if n < 0 or n % 2:
            raise ProtocolError(f"sample frame of {len(payload)} bytes")
        _, session, seq, tick, outputs, flags, late, a0, a1 = _SAMPLE_HEAD.unpack_from(payload)
        counts = struct.unpack_from(f"<{n // 2}H", payload, _SAMPLE_HEAD.size)
        return Sample(session, seq, tick, outputs, flags, late, (a0, a1), counts)
    if kind == ACK and len(payload) == _ACK.size:
        _, session, seq, cmd, cmd_seq, status, tick, outputs, flags = _ACK.unpack(payload)
        return Ack(session, seq, cmd, cmd_seq, status, -1 if tick == NO_TICK else tick, outputs, flags)
    if kind == INFO and len(payload) == _INFO.size:
        (_, session, seq, version, name, bits, n_adc, n_out, n_aout, max_rate, rate, cause, hb_ms,
         rx_errors) = _INFO.unpack(payload)
        return Info(session, seq, version, name.rstrip(b"\x00").decode("ascii", "replace"), bits, n_adc, n_out,
                    n_aout, max_rate, rate, RESET_CAUSES.get(cause, f"cause {cause}"), hb_ms, rx_errors)
    raise ProtocolError(f"frame type 0x{kind:02x} of {len(payload)} bytes")


class Splitter:
    """Bytes in, CRC-checked payloads out. A damaged frame (bad COBS, bad CRC, too long,
    too short) is counted in ``corrupt`` and costs only itself: the next delimiter starts
    the next frame."""

    def __init__(self) -> None:
        self._pending = b""
        self.corrupt = 0
        self.bytes = 0

    def feed(self, data: bytes) -> list[bytes]:
        self.bytes += len(data)
        parts = (self._pending + data).split(b"\x00")
        self._pending = parts.pop()
        if len(self._pending) > MAX_FRAME + 1:  # no delimiter for too long: garbage
            self._pending = b""
            self.corrupt += 1
        out = []
        for raw in parts:
            if not raw:
                continue  # delimiters back to back (the device sends one at power-on)
            payload = cobs_decode(raw) if len(raw) <= MAX_FRAME + 1 else None
            if payload is None or len(payload) < 3 or crc16(payload[:-2]) != int.from_bytes(payload[-2:], "little"):
                self.corrupt += 1
                continue
            out.append(payload[:-2])
        return out
