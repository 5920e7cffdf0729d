"""The sockets both faces open: a REQ socket for requests (CURVE keys optional) and a SUB
socket for events, subscribed to the welcome as well."""

from __future__ import annotations

import zmq
from fluidsense.common.names import WELCOME


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
        self._sub = None if session.pub_endpoint is None else setup_sub(ctx.socket(zmq.SUB), session.pub_endpoint,
                                                                        topics)

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

    def close(self) -> None:
        for sock in (self._req, self._sub):
            if sock is not None:
                sock.close()
        if self._own_ctx:
            self._ctx.term()
