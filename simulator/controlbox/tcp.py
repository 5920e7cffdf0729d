"""A TCP server that knows its connections, so closing it ends each of them cleanly
(their handlers see end-of-file and return) instead of leaving tasks to be cancelled."""

from __future__ import annotations

import abc
import asyncio

#: how long close() waits for connection handlers to notice the end
CLOSE_TIMEOUT_S = 2.0


class TcpServer(abc.ABC):
    def __init__(self, host: str, port: int):
        self.host, self.port = host, port
        self._server: asyncio.Server | None = None
        self._connections: dict[asyncio.Task, asyncio.StreamWriter] = {}

    async def start(self) -> None:
        self._server = await asyncio.start_server(self._accept, self.host, self.port)

    async def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._connections[task] = writer
        try:
            await self.serve(reader, writer)
        except ConnectionError:
            pass
        finally:
            self._connections.pop(task, None)
            writer.close()

    @abc.abstractmethod
    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """Handle one connection until it ends."""

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
        for writer in self._connections.values():
            writer.close()
        if self._connections:
            await asyncio.wait(list(self._connections), timeout=CLOSE_TIMEOUT_S)
        if self._server is not None:
            await self._server.wait_closed()
