"""Command socket: JSON requests on a ZeroMQ REP socket, one JSON reply each.

Every request gets a reply, malformed ones included (``{"ok": false, "error": ...}``),
and nothing a client sends can stop the daemon except ``shutdown``. Only JSON is ever
parsed: nothing is unpickled from the wire.
"""

from __future__ import annotations

import asyncio
import json
import logging
from collections.abc import Awaitable, Callable
from typing import Annotated, Any, Literal

import zmq
import zmq.asyncio
from pydantic import Field, TypeAdapter, ValidationError

from drivers.errors import FluidsenseError
from drivers.models import StrictModel, first_error
from drivers.scenes import Scene

log = logging.getLogger(__name__)

MAX_REQUEST_BYTES = 64 * 1024


class StatusCmd(StrictModel):
    cmd: Literal["status"]


class CycleCmd(StrictModel):
    cmd: Literal["cycle"]
    p0_kpa: float | None = Field(None, ge=-101, le=1000)
    label: str | None = Field(None, max_length=80)
    store_reference: bool = False


class AbortCmd(StrictModel):
    cmd: Literal["abort"]
    reason: str = Field("operator", max_length=200)


class ResetCmd(StrictModel):
    cmd: Literal["reset"]


class SceneCmd(StrictModel):
    cmd: Literal["scene"]
    scene: Scene


class TaskCmd(StrictModel):
    cmd: Literal["task"]
    file: str = Field(min_length=1, max_length=200, description="task file name in the daemon's task directory")
    order_mm: list[float] | None = Field(None, max_length=50)


class ShutdownCmd(StrictModel):
    cmd: Literal["shutdown"]


Command = Annotated[StatusCmd | CycleCmd | AbortCmd | ResetCmd | SceneCmd | TaskCmd | ShutdownCmd,
                    Field(discriminator="cmd")]
_ADAPTER = TypeAdapter(Command)
COMMANDS = ("status", "cycle", "abort", "reset", "scene", "task", "shutdown")


def parse(frames: list[bytes]) -> Any:
    """Decode and validate one request; raises ValueError with a reason for the client."""
    if len(frames) != 1:
        raise ValueError(f"expected one frame, got {len(frames)}")
    raw = frames[0]
    if len(raw) > MAX_REQUEST_BYTES:
        raise ValueError(f"request of {len(raw)} bytes exceeds {MAX_REQUEST_BYTES}")
    try:
        data = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"not a JSON object: {exc}") from None
    if not isinstance(data, dict):
        raise ValueError("request must be a JSON object like {\"cmd\": \"status\"}")
    if data.get("cmd") not in COMMANDS:
        raise ValueError(f"unknown command {data.get('cmd')!r}; known: {', '.join(COMMANDS)}")
    try:
        return _ADAPTER.validate_python(data)
    except ValidationError as exc:
        raise ValueError(first_error(exc, "request", skip=1)) from None


class CommandServer:
    def __init__(self, endpoint: str, handler: Callable[[Any], Awaitable[dict[str, Any]]] | None,
                 context: zmq.asyncio.Context | None = None, curve: tuple[str, str] | None = None):
        """``curve``: (server secret key file, directory of allowed client public keys)."""
        self.endpoint = endpoint
        self.handler = handler
        self._ctx = context or zmq.asyncio.Context.instance()
        self._auth = None
        self._sock = self._ctx.socket(zmq.REP)
        if curve is not None:
            self._enable_curve(*curve)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.setsockopt(zmq.MAXMSGSIZE, 4 * MAX_REQUEST_BYTES)
        self._sock.bind(endpoint)
        self.handled = 0
        self.rejected = 0
        log.info("commands on %s", endpoint)

    async def serve(self) -> None:
        while True:
            frames = await self._sock.recv_multipart()
            reply = await self.handle(frames)
            await self._sock.send(json.dumps(reply, default=str).encode())

    async def handle(self, frames: list[bytes]) -> dict[str, Any]:
        self.handled += 1
        try:
            cmd = parse(frames)
        except ValueError as exc:
            self.rejected += 1
            return {"ok": False, "error": str(exc)}
        try:
            return {"ok": True, **(await self.handler(cmd))}
        except FluidsenseError as exc:
            self.rejected += 1
            return {"ok": False, "error": str(exc)}
        except asyncio.CancelledError:
            raise
        except Exception as exc:  # noqa: BLE001 - a command must never kill the daemon
            self.rejected += 1
            log.exception("command %s failed", getattr(cmd, "cmd", "?"))
            return {"ok": False, "error": f"internal error: {type(exc).__name__}: {exc}"}

    def _enable_curve(self, secret_file: str, clients_dir: str) -> None:
        """Only clients whose public key is in ``clients_dir`` get in; traffic is encrypted."""
        import zmq.auth
        from zmq.auth.asyncio import AsyncioAuthenticator

        public, secret = zmq.auth.load_certificate(secret_file)
        if secret is None:
            raise ValueError(f"{secret_file} holds no secret key")
        self._auth = AsyncioAuthenticator(self._ctx)
        self._auth.start()
        self._auth.configure_curve(domain="*", location=clients_dir)
        self._sock.curve_secretkey = secret
        self._sock.curve_publickey = public
        self._sock.curve_server = True
        log.info("command socket: CURVE on, clients from %s", clients_dir)

    def close(self) -> None:
        self._sock.close()
        if self._auth is not None:
            self._auth.stop()
