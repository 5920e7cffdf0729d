"""A hand-written ZMTP 3.0 peer (NULL security) for hostile-client tests.

libzmq's own SUB/XSUB sockets keep every subscription they send in a trie of their own
(and crash tearing down a deep one), so a test that sends an 8 MB subscription, or tens
of thousands of them, speaks the wire protocol itself: what a hostile client would do.
"""

from __future__ import annotations

import socket
import struct


class RawPeer:
    def __init__(self, endpoint: str, socket_type: str = "XSUB", timeout_s: float = 10.0):
        if endpoint.startswith("ipc://"):
            self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            self.sock.settimeout(timeout_s)
            try:
                self.sock.connect(endpoint.removeprefix("ipc://"))
            except OSError:
                self.sock.close()  # refused: not left to the collector
                raise
        elif endpoint.startswith("tcp://"):
            host, port = endpoint.removeprefix("tcp://").rsplit(":", 1)
            self.sock = socket.create_connection((host, int(port)), timeout=timeout_s)
        else:
            raise ValueError(f"not an ipc or tcp endpoint: {endpoint}")
        try:
            self._handshake(socket_type)
        except BaseException:
            self.sock.close()  # refused or dropped (the outlet drops floods): not left to the collector
            raise

    def _handshake(self, socket_type: str) -> None:
        # greeting: signature, version 3.0, mechanism NULL, as-server 0, filler
        self.sock.sendall(b"\xff" + b"\x00" * 8 + b"\x7f" + b"\x03\x00" + b"NULL".ljust(20, b"\x00")
                          + b"\x00" * 32)
        kind = socket_type.encode()
        ready = b"\x05READY" + b"\x0bSocket-Type" + struct.pack(">I", len(kind)) + kind
        self._write(0x04, ready)
        # libzmq drops a peer whose first frames arrive with its READY: wait for the other side's
        self._read(64)
        flags, size = self._read(2)
        body = self._read(struct.unpack(">Q", bytes([size]) + self._read(7))[0] if flags & 0x02 else size)
        if not body.startswith(b"\x05READY"):
            raise ConnectionError(f"ZMTP handshake refused: {body[:40]!r}")

    def _read(self, n: int) -> bytes:
        data = b""
        while len(data) < n:
            chunk = self.sock.recv(n - len(data))
            if not chunk:
                raise ConnectionError("closed during the ZMTP handshake")
            data += chunk
        return data

    def _write(self, flags: int, body: bytes) -> None:
        if len(body) > 255:
            self.sock.sendall(bytes([flags | 0x02]) + struct.pack(">Q", len(body)) + body)
        else:
            self.sock.sendall(bytes([flags, len(body)]) + body)

    def send(self, body: bytes, more: bool = False) -> None:
        """One message frame; raises OSError once the other side has dropped us."""
        self._write(0x01 if more else 0x00, body)

    def send_oversized(self, size: int, chunk: int = 1 << 16) -> int:
        """Announce a frame of ``size`` bytes and stream its body until the other side
        hangs up; returns how many body bytes got written (kernel buffers included)."""
        written = 0
        try:
            self.sock.sendall(bytes([0x02]) + struct.pack(">Q", size))
            while written < size:
                n = min(chunk, size - written)
                self.sock.sendall(b"x" * n)
                written += n
        except OSError:
            pass
        return written

    def close(self) -> None:
        self.sock.close()
