"""The emulated control box, spoken to raw."""

from __future__ import annotations

import socket
import struct

MODBUS_PORT = 5020  # 502 needs privileges; the emulator's port is configurable


class RawRtde:
    def __init__(self, host: str):
        self.sock = socket.create_connection((host, 30004), timeout=10)

    def send(self, kind: str, payload: bytes = b"") -> None:
        self.sock.sendall(struct.pack(">HB", 3 + len(payload), ord(kind)) + payload)

    def recv(self) -> tuple[str, bytes]:
        size, kind = struct.unpack(">HB", self._exactly(3))
        return chr(kind), self._exactly(size - 3)

    def ask(self, kind: str, payload: bytes = b"") -> bytes:
        self.send(kind, payload)
        while True:
            got, body = self.recv()
            if got == kind:
                return body

    def _exactly(self, n: int) -> bytes:
        data = b""
        while len(data) < n:
            chunk = self.sock.recv(n - len(data))
            if not chunk:
                raise ConnectionError("closed")
            data += chunk
        return data

    def close(self) -> None:
        self.sock.close()


PORTS = (30004, 29999, 30003, MODBUS_PORT)


def free_host() -> str:
    """A 127.0.0.x whose box ports are free (the ports are fixed: tests are told apart by address)."""
    from support.harness import free_loopback

    return free_loopback(PORTS)
