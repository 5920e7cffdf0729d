"""RTDE server (port 30004), protocol version 2.

Every packet is ``uint16 size`` (header included), ``uint8 type``, payload, big-endian:

- ``V`` 86 request protocol version: ``uint16 version`` -> ``uint8 accepted``
- ``v`` 118 controller version: -> ``uint32 major, minor, bugfix, build``
- ``O`` 79 set up outputs: ``double frequency, "name,name,..."`` ->
  ``uint8 recipe id, "TYPE,TYPE,..."`` (``NOT_FOUND`` for unknown names, id 0 then)
- ``I`` 73 set up inputs: ``"name,..."`` -> ``uint8 recipe id, "TYPE,..."``
  (``NOT_FOUND``, or ``IN_USE`` when another connection writes that input; id 0 then)
- ``S`` 83 start / ``P`` 80 pause: -> ``uint8 accepted``
- ``U`` 85 data: ``uint8 recipe id`` + values, both ways
- ``M`` 77 text message: ``uint8 len, message, uint8 len, source, uint8 level``
  (from clients: logged; the box sends none)

Input recipes are numbered 1, 2, ... per connection in the order they were set up, and
inputs are applied whether or not the connection has started (ur_rtde's IO interface
never starts). Outputs are sent at the recipe's frequency from the controller cycle.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import struct
from collections import deque

from fluidsense.simulator.controlbox.box import ControlBox
from fluidsense.simulator.controlbox.rtde_vars import (
    Recipe,
    input_type,
    output_getter,
    output_type,
)
from fluidsense.simulator.controlbox.tcp import TcpServer

log = logging.getLogger(__name__)

V, v, O, I, S, P, U, M = (ord(c) for c in "VvOISPUM")
PROTOCOL_VERSION = 2
HEADER = struct.Struct(">HB")
#: drop output packages rather than queue more than this for a client that does not read
MAX_BACKLOG = 256 * 1024


class RtdeSession:
    """One client connection."""

    def __init__(self, server: RtdeServer, reader: asyncio.StreamReader, writer: asyncio.StreamWriter):
        self.server = server
        self.box = server.box
        self.reader, self.writer = reader, writer
        self.peer = writer.get_extra_info("peername")
        self.output: Recipe | None = None
        self._getters: list = []
        self._period = 0.0
        self._next_due = 0.0
        self._output_ids = 0
        self.inputs: dict[int, Recipe] = {}
        self.started = False
        self._dropping = False
        self._warned: set = set()
        self._late: deque[tuple[float, bytes]] = deque()  # (due at, package) under box.rtde_lag

    # -- sending ---------------------------------------------------------------------------
    def send(self, kind: int, payload: bytes = b"") -> None:
        if self.writer.is_closing():
            return
        self.writer.write(HEADER.pack(HEADER.size + len(payload), kind) + payload)

    def send_outputs(self, t: float) -> None:
        """Send the output recipe if it is due at controller time ``t``."""
        while self._late and self._late[0][0] <= t:
            self.send(U, self._late.popleft()[1])
        if not self.started or self.output is None or t + 1e-9 < self._next_due:
            return
        self._next_due += self._period
        if self._next_due <= t:
            # late (a loaded machine): send the current state, never a burst to catch up
            self._next_due = t + self._period
        if self.writer.transport.get_write_buffer_size() > MAX_BACKLOG:
            if not self._dropping:
                log.warning("RTDE %s does not read its data; dropping packages", self.peer)
            self._dropping = True
            return
        self._dropping = False
        values = self.box.lies.rtde(self.output.names, [g(self.box) for g in self._getters], t)
        package = bytes([self.output.id]) + self.output.pack(values)
        max_hz, lag_s = self.box.rtde_lag
        if lag_s > 0 and self._period >= 1.0 / max_hz:
            self._late.append((t + lag_s, package))
        else:
            self.send(U, package)

    # -- receiving ---------------------------------------------------------------------------
    async def run(self) -> None:
        log.info("RTDE client %s connected", self.peer)
        try:
            while True:
                size, kind = HEADER.unpack(await self.reader.readexactly(HEADER.size))
                if size < HEADER.size:
                    log.warning("RTDE %s: bad packet size %d; closing", self.peer, size)
                    break
                payload = await self.reader.readexactly(size - HEADER.size)
                try:
                    self.handle(kind, payload)
                except (struct.error, ValueError, IndexError) as exc:
                    self._warn_once(("malformed", kind), "malformed packet type %d ignored: %s", kind, exc)
                await self.writer.drain()
        except (asyncio.IncompleteReadError, ConnectionError):
            pass
        finally:
            self.close()
            # a client gone with a reset leaves its exception in the stream's close future too;
            # unretrieved, asyncio logs it with a traceback when the future is collected
            with contextlib.suppress(Exception):
                await self.writer.wait_closed()
            log.info("RTDE client %s disconnected", self.peer)

    def _warn_once(self, key, message: str, *args) -> None:
        """Log a client's mistake once, not at every package it repeats it in."""
        if key not in self._warned:
            self._warned.add(key)
            log.warning("RTDE %s: " + message, self.peer, *args)

    def close(self) -> None:
        self.started = False
        for name, owner in list(self.box.input_owners.items()):
            if owner is self:
                del self.box.input_owners[name]
        self.server.sessions.discard(self)
        if not self.writer.is_closing():
            self.writer.close()

    def handle(self, kind: int, payload: bytes) -> None:
        handler = {V: self._version, v: self._controller_version, O: self._setup_outputs,
                   I: self._setup_inputs, S: self._start, P: self._pause, U: self._data,
                   M: self._text}.get(kind)
        if handler is None:
            self._warn_once(("type", kind), "unknown packet type %d ignored", kind)
            return
        handler(payload)

    def _version(self, payload: bytes) -> None:
        (wanted,) = struct.unpack(">H", payload[:2])
        accepted = wanted == PROTOCOL_VERSION
        if not accepted:
            log.warning("RTDE %s asked for protocol version %d; only %d is emulated",
                        self.peer, wanted, PROTOCOL_VERSION)
        self.send(V, bytes([accepted]))

    def _controller_version(self, payload: bytes) -> None:
        self.send(v, struct.pack(">IIII", *self.box.config.version))

    def _setup_outputs(self, payload: bytes) -> None:
        (frequency,) = struct.unpack(">d", payload[:8])
        names = _names(payload[8:])
        types = [output_type(n) or "NOT_FOUND" for n in names]
        if "NOT_FOUND" in types or not names:
            missing = [n for n, t in zip(names, types) if t == "NOT_FOUND"]
            log.warning("RTDE %s: outputs not found: %s", self.peer, missing)
            self.send(O, bytes([0]) + ",".join(types).encode())
            return
        max_hz = self.box.config.control_hz
        if not 0 < frequency <= max_hz:
            log.warning("RTDE %s asked for %.1f Hz; sending at %.1f Hz", self.peer, frequency, max_hz)
            frequency = max_hz
        self._output_ids += 1
        self.output = Recipe(self._output_ids, names, types)
        self._getters = [output_getter(n) for n in names]
        self._period = 1.0 / frequency
        log.info("RTDE %s: output recipe %d, %d variables at %.0f Hz", self.peer, self.output.id,
                 len(names), frequency)
        self.send(O, bytes([self.output.id]) + ",".join(types).encode())

    def _setup_inputs(self, payload: bytes) -> None:
        names = _names(payload)
        types = []
        for name in names:
            owner = self.box.input_owners.get(name)
            if owner is not None and owner is not self:
                types.append("IN_USE")
            else:
                types.append(input_type(name) or "NOT_FOUND")
        if not names or any(t in ("NOT_FOUND", "IN_USE") for t in types):
            log.warning("RTDE %s: input recipe refused: %s", self.peer,
                        [f"{n}={t}" for n, t in zip(names, types) if t in ("NOT_FOUND", "IN_USE")])
            self.send(I, bytes([0]) + ",".join(types).encode())
            return
        recipe_id = len(self.inputs) + 1
        if recipe_id > 255:
            self.send(I, bytes([0]) + ",".join(types).encode())
            return
        for name in names:
            self.box.input_owners[name] = self
        self.inputs[recipe_id] = Recipe(recipe_id, names, types)
        log.debug("RTDE %s: input recipe %d: %s", self.peer, recipe_id, names)
        self.send(I, bytes([recipe_id]) + ",".join(types).encode())

    def _start(self, payload: bytes) -> None:
        self.started = True
        self._next_due = self.box.model.t
        log.info("RTDE %s: started", self.peer)
        self.send(S, bytes([1]))

    def _pause(self, payload: bytes) -> None:
        self.started = False
        log.info("RTDE %s: paused", self.peer)
        self.send(P, bytes([1]))

    def _data(self, payload: bytes) -> None:
        recipe_id = payload[0]
        recipe = self.inputs.get(recipe_id)
        if recipe is None:
            self._warn_once(("recipe", recipe_id), "data for unknown input recipe %d ignored", recipe_id)
            return
        body = payload[1:]
        if len(body) != recipe.struct.size:
            self._warn_once(("size", recipe_id), "recipe %d expects %d bytes, got %d; ignored",
                            recipe_id, recipe.struct.size, len(body))
            return
        values = recipe.unpack(body)
        log.debug("RTDE %s: recipe %d: %s", self.peer, recipe.id, values)
        self.box.write_inputs(values)

    def _text(self, payload: bytes) -> None:
        try:
            n = payload[0]
            message = payload[1:1 + n].decode(errors="replace")
            k = payload[1 + n]
            source = payload[2 + n:2 + n + k].decode(errors="replace")
        except IndexError:
            message, source = payload.decode(errors="replace"), "?"
        log.info("RTDE %s text from %s: %s", self.peer, source, message)


def _names(raw: bytes) -> list[str]:
    # ur_rtde ends its lists with a comma; an empty name is not a variable
    return [n.strip() for n in raw.decode(errors="replace").split(",") if n.strip()]


class RtdeServer(TcpServer):
    """Listens for RTDE clients and feeds them from the box's controller cycle."""

    def __init__(self, box: ControlBox, host: str, port: int):
        super().__init__(host, port)
        self.box = box
        self.sessions: set[RtdeSession] = set()

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        session = RtdeSession(self, reader, writer)
        self.sessions.add(session)
        await session.run()

    def tick(self) -> None:
        t = self.box.model.t
        for session in list(self.sessions):
            session.send_outputs(t)
