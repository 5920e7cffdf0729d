"""The sockets both faces open: a REQ socket for requests (CURVE keys optional) and a SUB
socket for events, subscribed to the welcome as well, with a monitor that tells "nobody
there" from "something there that is not a publisher" when no welcome comes."""

from __future__ import annotations

import itertools

import zmq
from fluidsense.common.names import WELCOME

from .types import NoWelcome

#: what the SUB socket's monitor listens for: a TCP or IPC connection made, dropped, and a
#: ZMTP handshake completed (a peer of a kind a SUB may talk to)
_WATCHED = zmq.EVENT_CONNECTED | zmq.EVENT_DISCONNECTED | zmq.EVENT_HANDSHAKE_SUCCEEDED
_monitors = itertools.count()


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


class Sockets:
    """What the two faces share: the session (core.Session), a REQ socket made when a
    request needs one, the SUB socket (none for a client made with ``pub=None``)."""

    def __init__(self, session, ctx: zmq.Context, own_ctx: bool, curve: tuple[str, str] | None,
                 topics: tuple[str, ...]):
        self._session, self._ctx, self._own_ctx = session, ctx, own_ctx
        self._keys = curve_keys(curve)
        self._req: zmq.Socket | None = None
        self._sub = self._monitor = None
        self._seen: set[int] = set()
        if session.pub_endpoint is not None:
            self._sub = ctx.socket(zmq.SUB)
            # the monitor is read without blocking from a plain socket on the same
            # underlying context, whichever face (blocking or asyncio) this is
            address = f"inproc://fluidsense-client-monitor-{next(_monitors)}-{id(self)}"
            self._sub.monitor(address, _WATCHED)
            self._monitor = zmq.Context.shadow(ctx.underlying).socket(zmq.PAIR)
            self._monitor.setsockopt(zmq.LINGER, 0)
            self._monitor.connect(address)
            setup_sub(self._sub, session.pub_endpoint, topics)

    cmd_endpoint = property(lambda self: self._session.cmd_endpoint)
    pub_endpoint = property(lambda self: self._session.pub_endpoint)
    timeout_s = property(lambda self: self._session.timeout_s)
    event_timeout_s = property(lambda self: self._session.event_timeout_s)

    def _request_socket(self) -> zmq.Socket:
        if self._req is None:
            self._req = setup_req(self._ctx.socket(zmq.REQ), self.cmd_endpoint, self._keys)
        return self._req

    def _drop_request_socket(self) -> None:
        """A REQ socket that missed its reply is stuck: the next request gets a new one."""
        self._req.close()
        self._req = None

    def _explained(self, exc: NoWelcome) -> NoWelcome:
        """Why no welcome came, from what the monitor saw: connections made and dropped
        without a completed handshake are a peer of the wrong kind (the command socket,
        as when cmd and pub are swapped in Gripper(cmd, pub)), not a daemon that is not
        running."""
        from zmq.utils.monitor import parse_monitor_message

        while self._monitor is not None and self._monitor.poll(0):
            self._seen.add(int(parse_monitor_message(self._monitor.recv_multipart())["event"]))
        if zmq.EVENT_CONNECTED in self._seen and zmq.EVENT_HANDSHAKE_SUCCEEDED not in self._seen:
            return NoWelcome(f"no welcome from {self.pub_endpoint}: a socket listens there but drops a subscriber "
                             "at the handshake: it is not the daemon's publisher (is it its command endpoint? "
                             "Gripper(cmd, pub) takes the command endpoint first), or its CURVE keys differ")
        return exc

    def close(self) -> None:
        if self._monitor is not None:
            self._sub.disable_monitor()
            self._monitor.close()
        for sock in (self._req, self._sub):
            if sock is not None:
                sock.close()
        if self._own_ctx:
            self._ctx.term()
