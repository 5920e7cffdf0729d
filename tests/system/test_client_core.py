"""The client library's one core (fluidsense/client/core.py) and its two faces.

The core's calls do no I/O: here they are driven step by step from a script (what the
daemon would send), then the blocking and the asyncio face, and the CLI's ``send_command``,
run against a real ZeroMQ ROUTER in this process that leaves the first request
unanswered: the request socket must be made again for the next one to get through.

(Its in-process tests: tests/unit/test_client_core.py.)
"""

from __future__ import annotations

import asyncio
import json
import threading

import pytest
import zmq
import zmq.asyncio
from fluidsense.client import AsyncGripper, Gripper, NoReply


# ------------------------------------------------------------------ the faces on a real socket
class Router:
    """A ROUTER on a thread of its own: it leaves the first request unanswered, and
    answers each later one with ``reply``."""

    def __init__(self, ctx: zmq.Context, endpoint: str, reply: dict):
        self.sock = ctx.socket(zmq.ROUTER)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.bind(endpoint)
        self.reply, self.seen = reply, []
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        try:
            while True:
                *envelope, body = self.sock.recv_multipart()
                self.seen.append(json.loads(body))
                if len(self.seen) > 1:
                    self.sock.send_multipart([*envelope, json.dumps(self.reply).encode()])
        except zmq.ContextTerminated:
            self.sock.close()


def test_the_blocking_face_makes_its_request_socket_again_after_a_timeout(tmp_path):
    ctx = zmq.Context()
    Router(ctx, f"ipc://{tmp_path}/cmd", {"ok": True, "state": "idle"})
    with Gripper(f"ipc://{tmp_path}/cmd", None, timeout_s=0.05, context=ctx) as g:
        with pytest.raises(NoReply):
            g.status()
        assert g.request({"cmd": "status"}, timeout_s=30.0)["state"] == "idle"  # a stuck REQ could not send
    ctx.term()


def test_the_asyncio_face_makes_its_request_socket_again_after_a_timeout(tmp_path):
    ctx = zmq.Context()
    router = Router(ctx, f"ipc://{tmp_path}/cmd", {"ok": True, "aborted": False})

    async def body():
        async with AsyncGripper(f"ipc://{tmp_path}/cmd", None, timeout_s=0.05) as g:
            with pytest.raises(NoReply):
                await g.abort("first")
            return await g.request({"cmd": "abort", "reason": "second"}, timeout_s=30.0)

    assert asyncio.run(body())["aborted"] is False
    assert [m["reason"] for m in router.seen] == ["first", "second"]
    ctx.term()


def test_send_command_gives_an_error_reply_as_it_came_and_a_silence_as_a_timeout(tmp_path):
    from fluidsense.cli.monitor import send_command

    ctx = zmq.Context()
    Router(ctx, f"ipc://{tmp_path}/cmd", {"ok": False, "error": "busy: cycle 2 is in hold"})
    with pytest.raises(TimeoutError, match=r"no reply from ipc://.* within 0.05 s: the daemon may not be running"):
        send_command(f"ipc://{tmp_path}/cmd", {"cmd": "cycle"}, 0.05)
    assert send_command(f"ipc://{tmp_path}/cmd", {"cmd": "cycle"}, 30.0) == {"ok": False,
                                                                             "error": "busy: cycle 2 is in hold"}
    ctx.term()


@pytest.mark.parametrize("face", ["sync", "asyncio"])
def test_swapped_endpoints_are_named_not_taken_for_a_daemon_that_is_down(face, tmp_path):
    """Gripper(pub, cmd) by mistake: the daemon's command socket (a ROUTER) and its
    publisher (an XPUB), bound here as the daemon binds them. The client connects its SUB
    to the ROUTER: the handshake fails, and the error says so instead of asking whether
    the daemon runs; with nothing bound at all it still asks that."""
    cmd, pub, nobody = (f"ipc://{tmp_path}/{name}" for name in ("cmd", "pub", "nobody"))
    ctx = zmq.Context()
    router, xpub = ctx.socket(zmq.ROUTER), ctx.socket(zmq.XPUB)
    router.bind(cmd)
    xpub.bind(pub)

    def status(cmd_endpoint: str, pub_endpoint: str) -> str:
        if face == "sync":
            with Gripper(cmd_endpoint, pub_endpoint, timeout_s=1.0) as g, pytest.raises(NoReply) as err:
                g.status()
            return str(err.value)

        async def body():
            async with AsyncGripper(cmd_endpoint, pub_endpoint, timeout_s=1.0) as g:
                with pytest.raises(NoReply) as err:
                    await g.status()
                return str(err.value)

        return asyncio.run(body())

    try:
        swapped = status(pub, cmd)
        down = status(nobody + "-cmd", nobody)
    finally:
        router.close(0)
        xpub.close(0)
        ctx.term()
    assert swapped.startswith(f"no welcome from {cmd}: a socket listens there but drops a subscriber"), swapped
    assert "is it its command endpoint?" in swapped and "daemon running" not in swapped
    assert down == f"no welcome from {nobody}: is the daemon running?"
