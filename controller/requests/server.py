"""Command socket: JSON requests on a ZeroMQ ROUTER socket, one JSON reply each.

Clients talk to it with REQ, or with DEALER sending the empty delimiter frame a REQ socket
sends. The server owns the envelope: a message is ``[routing frames..., b"", body]``. One
without the delimiter cannot be answered and is dropped and counted; every other one gets
exactly one reply, malformed bodies included (``{"ok": false, "error": ...}``). A body is
size- and depth-checked before it is parsed, requests are handled one at a time, and
nothing a client sends can stop the daemon except ``shutdown``. Only JSON is ever parsed:
nothing is unpickled from the wire. Limits: docs/zmq-schema.md. What a request means is
not the socket's business: the JSON object goes to ``answer`` (the dispatcher), which
validates it and replies.
"""

from __future__ import annotations

import asyncio
import json
import logging
from collections.abc import Awaitable, Callable
from typing import Any

import zmq
import zmq.asyncio
from fluidsense.common.errors import FluidsenseError
from fluidsense.controller.config import CurveKeys
from fluidsense.controller.config.curve import read_secret_key

log = logging.getLogger(__name__)

#: a decoded request -> its reply (without ``ok``), or a FluidsenseError saying why not
Answer = Callable[[dict[str, Any]], Awaitable[dict[str, Any]]]

MAX_REQUEST_BYTES = 64 * 1024
MAX_DEPTH = 32  # json.loads recurses once per level: a deep document is a RecursionError
# libzmq's MAXMSGSIZE limits each frame: a larger one drops the connection without a reply,
# so requests between the two limits still get a "too large" error reply
MAX_FRAME_BYTES = 4 * MAX_REQUEST_BYTES
MAX_HOPS = 8  # routing frames before the delimiter: one per ROUTER/DEALER proxy on the way
MAX_ROUTING_ID_BYTES = 255  # ZeroMQ's own limit on a routing id
HWM = 64  # messages queued per client, each way


def too_deep(raw: bytes, limit: int = MAX_DEPTH) -> bool:
    """Whether ``[``/``{`` nest deeper than ``limit`` outside JSON strings: a scan of the
    bytes, so that json.loads never sees a document that would make it recurse deeply."""
    if raw.count(b"[") + raw.count(b"{") <= limit:
        return False
    depth = 0
    in_string = escaped = False
    for byte in raw:
        if in_string:
            if escaped:
                escaped = False
            elif byte == 0x5C:  # backslash
                escaped = True
            elif byte == 0x22:  # quote
                in_string = False
        elif byte == 0x22:
            in_string = True
        elif byte in (0x5B, 0x7B):  # [ {
            depth += 1
            if depth > limit:
                return True
        elif byte in (0x5D, 0x7D):  # ] }
            depth -= 1
    return False


class _Refused(ValueError):
    """JSON that parses but that a request may not contain."""


def _no_constant(name: str) -> Any:
    raise _Refused(f"{name} is not a number in JSON")


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise _Refused(f"duplicate key {key!r}")
        out[key] = value
    return out


def decode(frames: list[bytes]) -> dict[str, Any]:
    """Check and decode one request body into a JSON object; raises ValueError with a
    reason for the client. Size and depth are checked before anything is parsed."""
    if len(frames) != 1:
        raise ValueError(f"expected one frame, got {len(frames)}")
    raw = frames[0]
    if len(raw) > MAX_REQUEST_BYTES:
        raise ValueError(f"request of {len(raw)} bytes exceeds {MAX_REQUEST_BYTES}")
    if too_deep(raw):
        raise ValueError(f"request nested deeper than {MAX_DEPTH} levels")
    try:
        data = json.loads(raw.decode("utf-8"), parse_constant=_no_constant, object_pairs_hook=_unique_keys)
    except _Refused as exc:
        raise ValueError(str(exc)) from None
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:  # ValueError: also huge integers
        raise ValueError(f"not a JSON object: {exc}") from None
    if not isinstance(data, dict):
        raise ValueError("request must be a JSON object like {\"cmd\": \"status\"}")
    return data


def split_envelope(frames: list[bytes]) -> tuple[list[bytes], list[bytes]] | None:
    """(routing frames up to and including the empty delimiter, body frames) of a message
    as the ROUTER socket received it (its first frame is the peer's routing id); None when
    it cannot be answered: no delimiter, or routing frames no ZeroMQ peer would send."""
    try:
        end = frames.index(b"", 1)
    except ValueError:
        return None
    route = frames[:end]
    if len(route) > 1 + MAX_HOPS or any(len(f) > MAX_ROUTING_ID_BYTES for f in route):
        return None
    return frames[:end + 1], frames[end + 1:]


def _encode(reply: dict[str, Any]) -> bytes:
    try:
        return json.dumps(reply, default=str).encode()
    except (TypeError, ValueError) as exc:  # a reply that cannot be encoded must still be a reply
        log.error("reply not encodable: %s", exc)
        return json.dumps({"ok": False, "error": f"internal error: reply not encodable: {exc}"}).encode()


class CommandServer:
    def __init__(self, endpoint: str, context: zmq.asyncio.Context | None = None, curve: CurveKeys | None = None,
                 instance: str | None = None):
        """Bound here; ``curve``: the server's secret key and the clients let in
        (CurveKeys). The daemon binds its sockets before it touches a device; what answers
        comes with ``serve``, once the controller runs. ``instance``: the daemon's id (its
        publisher's), put in every reply that names a cycle and in ``status``."""
        self.endpoint = endpoint
        self.instance = instance
        self._ctx = context or zmq.asyncio.Context.instance()
        self._auth = None
        self._sock = self._ctx.socket(zmq.ROUTER)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.setsockopt(zmq.MAXMSGSIZE, MAX_FRAME_BYTES)
        self._sock.setsockopt(zmq.RCVHWM, HWM)
        self._sock.setsockopt(zmq.SNDHWM, HWM)
        try:
            if curve is not None:
                self._enable_curve(curve)
            self._sock.bind(endpoint)
        except BaseException:
            self.close()
            raise
        self.handled = 0  # replies sent
        self.rejected = 0  # of which error replies
        self.malformed_dropped = 0  # messages that could not be answered
        log.info("commands on %s", endpoint)

    @property
    def stats(self) -> dict[str, int]:
        return {"handled": self.handled, "rejected": self.rejected, "malformed_dropped": self.malformed_dropped}

    async def serve(self, answer: Answer) -> None:
        """Answer requests with ``answer`` until cancelled; no message can end this loop."""
        while True:
            try:
                frames = await self._sock.recv_multipart()
            except zmq.Again:  # woken without a message: nothing to do
                continue
            try:
                await self._reply(frames, answer)
            except asyncio.CancelledError:
                raise
            except Exception:  # noqa: BLE001 - a message must never end the command socket
                self.malformed_dropped += 1
                log.exception("command message dropped")
            # back-to-back requests complete without suspending: let the sample loop run
            await asyncio.sleep(0)

    async def _reply(self, frames: list[bytes], answer: Answer) -> None:
        parts = split_envelope(frames)
        if parts is None:
            self.malformed_dropped += 1
            if self.malformed_dropped & (self.malformed_dropped - 1) == 0:  # 1, 2, 4, ...: no log flood
                log.warning("command socket: %d malformed messages dropped (no envelope to reply to)",
                            self.malformed_dropped)
            return
        envelope, body = parts
        reply = await self.handle(body, answer)
        # a ROUTER never blocks: a reply to a client that has gone or stopped reading is dropped
        await self._sock.send_multipart([*envelope, _encode(reply)])

    async def handle(self, frames: list[bytes], answer: Answer) -> dict[str, Any]:
        self.handled += 1
        try:
            request = decode(frames)
        except ValueError as exc:
            self.rejected += 1
            return {"ok": False, "error": str(exc)}
        try:
            reply = {"ok": True, **(await answer(request))}
            # a client waiting for this cycle's events takes them only from the instance
            # that started it: cycle ids start again at 1 after a restart
            if self.instance is not None and ("cycle_id" in reply or request.get("cmd") == "status"):
                reply["instance"] = self.instance
            return reply
        except FluidsenseError as exc:
            self.rejected += 1
            return {"ok": False, "error": str(exc)}
        except asyncio.CancelledError:
            raise
        except Exception as exc:  # noqa: BLE001 - a command must never kill the daemon
            self.rejected += 1
            log.exception("command %s failed", request.get("cmd", "?"))
            return {"ok": False, "error": f"internal error: {type(exc).__name__}: {exc}"}

    def _enable_curve(self, keys: CurveKeys) -> None:
        """Only clients whose public key is in ``clients_dir`` get in (any key only with
        ``allow_any_client``); traffic is encrypted."""
        from zmq.auth import CURVE_ALLOW_ANY
        from zmq.auth.asyncio import AsyncioAuthenticator

        public, secret = read_secret_key(keys.server_secret_file)
        self._auth = AsyncioAuthenticator(self._ctx)
        self._auth.start()
        self._auth.configure_curve(domain="*", location=CURVE_ALLOW_ANY if keys.allow_any_client else keys.clients_dir)
        self._sock.curve_secretkey = secret
        self._sock.curve_publickey = public
        self._sock.curve_server = True
        log.info("command socket: CURVE on, %s", "ANY client key" if keys.allow_any_client
                 else f"clients from {keys.clients_dir}")

    def close(self) -> None:
        self._sock.close()
        if self._auth is not None:
            self._auth.stop()
