"""Sockets and messages shared by the sync and asyncio clients."""

from __future__ import annotations

import json
from typing import Any

import zmq

from .types import Event

WELCOME = b"hello"


def curve_keys(curve: tuple[str, str] | None) -> tuple[bytes, bytes, bytes] | None:
    """(client public, client secret, server public) from (client secret key file, server
    public key file), as ``fluidsense keys`` writes them."""
    if curve is None:
        return None
    import zmq.auth

    public, secret = zmq.auth.load_certificate(curve[0])
    server, _ = zmq.auth.load_certificate(curve[1])
    if secret is None:
        raise ValueError(f"{curve[0]} holds no secret key")
    return public, secret, server


def setup_req(sock: zmq.Socket, endpoint: str, keys: tuple[bytes, bytes, bytes] | None) -> zmq.Socket:
    sock.setsockopt(zmq.LINGER, 0)
    if keys is not None:
        sock.curve_publickey, sock.curve_secretkey, sock.curve_serverkey = keys
    sock.connect(endpoint)
    return sock


def setup_sub(sock: zmq.Socket, endpoint: str, topics: tuple[str, ...]) -> zmq.Socket:
    sock.setsockopt(zmq.LINGER, 0)
    for topic in (*topics, WELCOME.decode()):
        sock.setsockopt(zmq.SUBSCRIBE, topic.encode())
    sock.connect(endpoint)
    return sock


def request_body(cmd: str, **fields: Any) -> dict[str, Any]:
    return {"cmd": cmd, **{k: v for k, v in fields.items() if v is not None}}


def decode(frames: list[bytes]) -> Event | None:
    """An event, or None for the welcome frame and anything that is not a message."""
    if len(frames) != 2:
        return None
    try:
        return Event.of(json.loads(frames[1]))
    except (ValueError, KeyError, TypeError):
        return None


def matches(ev: Event, topic: str, cycle_id: int | None) -> bool:
    return ev.topic == topic and (cycle_id is None or ev.data.get("cycle_id") == cycle_id)
