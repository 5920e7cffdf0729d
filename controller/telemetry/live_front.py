"""The live view's public port: accepts both names of the Foxglove WebSocket protocol.

The Foxglove SDK's server (foxglove-sdk) accepts only the subprotocol ``foxglove.sdk.v1``
and answers any other with HTTP 400. Lichtblick (the open fork of Foxglove Studio) and
older Foxglove clients ask for ``foxglove.websocket.v1``, the name of the same protocol
before the SDK renamed it: the messages, their opcodes and fields are the same (the
Foxglove WebSocket protocol specification, foxglove/ws-protocol docs/spec.md, and the
SDK's own statement that ``foxglove.sdk.v1`` is that protocol under a new name).

So the SDK listens on a loopback port of its own and this front, on the configured
address, passes every connection through byte for byte. Only the opening handshake is
read: a client that offers ``foxglove.websocket.v1`` and not ``foxglove.sdk.v1`` has that
name replaced in its request, and the server's choice is named back to it in the response.
Everything after the handshake (the WebSocket frames) is copied unchanged, each direction
awaiting the other end's reading, so a slow viewer still meets the SDK's per-viewer
backlog (it drops the oldest) and holds at most a read buffer here.
"""

from __future__ import annotations

import asyncio
import logging
import re
import threading

log = logging.getLogger("fluidsense.controller.telemetry.live_front")

SDK = b"foxglove.sdk.v1"
LEGACY = b"foxglove.websocket.v1"
MAX_HEAD_BYTES = 16 * 1024  # a browser's handshake is well under 2 kB
HEAD_TIMEOUT_S = 10.0
CHUNK = 64 * 1024
PROTOCOL_LINE = re.compile(rb"^(sec-websocket-protocol:[ \t]*)(.*?)([ \t]*)$", re.IGNORECASE | re.MULTILINE)


def offered(head: bytes) -> list[bytes]:
    """The subprotocols a handshake offers (every Sec-WebSocket-Protocol line, in order)."""
    return [p.strip() for m in PROTOCOL_LINE.finditer(head) for p in m.group(2).split(b",") if p.strip()]


def rename_request(head: bytes) -> tuple[bytes, bool]:
    """The request as the SDK takes it, and whether the client spoke the old name."""
    names = offered(head)
    if SDK in names or LEGACY not in names:
        return head, False
    return PROTOCOL_LINE.sub(lambda m: m.group(1) + m.group(2).replace(LEGACY, SDK) + m.group(3), head), True


def rename_response(head: bytes) -> bytes:
    """The SDK's response as a client of the old name expects it: its own name chosen."""
    return PROTOCOL_LINE.sub(lambda m: m.group(1) + m.group(2).replace(SDK, LEGACY) + m.group(3), head)


async def _head(reader: asyncio.StreamReader) -> bytes:
    """An HTTP head, up to and with its blank line."""
    return await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HEAD_TIMEOUT_S)


async def _copy(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    try:
        while chunk := await reader.read(CHUNK):
            writer.write(chunk)
            await writer.drain()  # the far end reads first: no buffer grows here
    except (ConnectionError, asyncio.IncompleteReadError):
        pass
    finally:
        writer.close()


class Front:
    """The public listener, on an event loop in a thread of its own."""

    def __init__(self, host: str, port: int, sdk_port: int):
        self.sdk_port = sdk_port
        self.loop = asyncio.new_event_loop()
        self.server = self.loop.run_until_complete(
            asyncio.start_server(self._serve, host, port, limit=MAX_HEAD_BYTES, reuse_address=True))
        self.port = self.server.sockets[0].getsockname()[1]
        self.thread = threading.Thread(target=self.loop.run_forever, name="live-front", daemon=True)
        self.thread.start()

    async def _serve(self, client_r: asyncio.StreamReader, client_w: asyncio.StreamWriter) -> None:
        server_w = None
        try:
            request, legacy = rename_request(await _head(client_r))
            server_r, server_w = await asyncio.open_connection("127.0.0.1", self.sdk_port, limit=MAX_HEAD_BYTES)
            server_w.write(request)
            await server_w.drain()
            response = await _head(server_r)
            client_w.write(rename_response(response) if legacy else response)
            await client_w.drain()
        except (OSError, asyncio.IncompleteReadError, asyncio.LimitOverrunError, asyncio.TimeoutError) as exc:
            log.info("live view: a connection ended in its handshake: %s", type(exc).__name__)
            client_w.close()
            if server_w is not None:
                server_w.close()
            return
        await asyncio.gather(_copy(client_r, server_w), _copy(server_r, client_w))

    def close(self) -> None:
        async def stop() -> None:
            self.server.close()
            for task in asyncio.all_tasks():
                if task is not asyncio.current_task():
                    task.cancel()

        asyncio.run_coroutine_threadsafe(stop(), self.loop).result(5)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5)
