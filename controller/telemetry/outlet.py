"""The publisher's outlet process: ``python -m fluidsense.controller.telemetry.outlet ARGS_JSON``.

It owns the public XPUB socket, so that subscribers, whoever they are, cost the daemon
nothing. Subscriptions are untrusted input that libzmq handles inside whichever call the
application makes on the socket: a peer streaming distinct subscription prefixes keeps
one such call busy for as long as it streams, and each prefix costs about 50 bytes per
byte in libzmq's subscription trie (one 8 MB subscription cost 880 MB; 97,000 prefixes of
63 bytes a second, 320 MB a second). Inside the daemon that froze the sample loop and
SIGTERM. Here it can only stop the outlet, which is bounded and restarted:

- a frame is at most MAX_FRAME_BYTES (MAXMSGSIZE): a larger one drops its connection at
  the frame header;
- frames that do not belong (subscriptions no topic starts with, anything that is not a
  subscription) are counted; past SUBSCRIPTION_BUDGET every subscriber connection is
  dropped (unbind, bind again), which frees the trie; well-behaved subscribers reconnect
  by themselves and get the welcome again;
- the process's data size is capped (RLIMIT_DATA): a flood faster than the budget can act
  on ends the outlet (libzmq aborts on a failed allocation) and the daemon starts another.

XPUB_MANUAL bounds nothing here: libzmq 4.3 then keeps every subscription a peer sends
in a second trie, to unsubscribe it when the peer leaves. Matching stays ZeroMQ's own: a
prefix gets every topic that starts with it.

ARGS_JSON: ``endpoint`` (public, bound here), ``inlet`` (ipc endpoint bound here, in a
directory only the daemon's user can enter; the daemon PUSHes encoded messages to it),
``hwm`` (the XPUB's per-subscriber high-water mark), ``parent_pid``, ``memory_cap_mb``,
``instance`` (the daemon's id, sent in the welcome).
Prints ``ok`` once both are bound, or ``error ERRNO MESSAGE``. A single-frame ``stop``
message on the inlet ends it after the messages before it were sent (LINGER).
"""

from __future__ import annotations

import ctypes
import json
import logging
import os
import resource
import signal
import sys
import time
from typing import Any

import zmq
from fluidsense.common.names import TOPICS, WELCOME, welcome_frame

log = logging.getLogger("fluidsense.controller.telemetry.outlet")

KNOWN = tuple(t.encode() for t in TOPICS) + (WELCOME,)
STOP = [b"stop"]  # never a published message: those are two frames
# a frame's size limit also applies to the ZMTP handshake (a subscriber's READY command is
# about 30 bytes; other ZeroMQ libraries may add properties)
MAX_FRAME_BYTES = 256
# the daemon's own messages, through a socket only its user can reach: a pressure batch is
# about 2.5 kB, a task summary a few
MAX_MESSAGE_BYTES = 16 * 2**20
SUBSCRIPTION_BUDGET = 500  # foreign frames between connection resets: a few MB of trie
RCVHWM = 64  # subscription frames queued per subscriber
BATCH = 1000  # frames moved per turn, each way, so that neither direction starves the other
LINGER_MS = 1000  # the last messages (the daemon's "controller stopped") still go out
REBIND_RETRY_S = 0.02
REBIND_GIVE_UP_S = 5.0
PR_SET_PDEATHSIG = 1


def is_known_prefix(prefix: bytes) -> bool:
    """Whether a subscription to ``prefix`` receives any published message."""
    return any(name.startswith(prefix) for name in KNOWN)


class Outlet:
    def __init__(self, ctx: zmq.Context, endpoint: str, inlet: str, hwm: int, instance: str = ""):
        self.xpub = ctx.socket(zmq.XPUB)
        self.xpub.setsockopt(zmq.SNDHWM, hwm)
        self.xpub.setsockopt(zmq.RCVHWM, RCVHWM)
        self.xpub.setsockopt(zmq.MAXMSGSIZE, MAX_FRAME_BYTES)
        self.xpub.setsockopt(zmq.LINGER, LINGER_MS)
        # The welcome says "your subscriptions are in": sent once the subscriber's subscription
        # to hello has reached the trie, which its earlier ones (its topics, sent first) reached
        # before it. XPUB_WELCOME_MSG went out when the connection was attached, before libzmq had
        # read any subscription: an event published right after it could miss a subscriber whose
        # subscriptions the outlet's I/O thread had not read yet (seen: a monitor lost the first
        # state of the cycle it asked for, on a loaded machine). XPUB_VERBOSE passes every
        # subscription up, so that each subscriber's hello is seen, not only the first one.
        self.xpub.setsockopt(zmq.XPUB_VERBOSE, 1)
        # the daemon's instance id in it: a subscriber tells a restarted daemon on the same port
        self.welcome = welcome_frame(instance) if instance else WELCOME
        self.inlet = ctx.socket(zmq.PULL)
        self.inlet.setsockopt(zmq.RCVHWM, max(hwm, 10_000))
        self.inlet.setsockopt(zmq.MAXMSGSIZE, MAX_MESSAGE_BYTES)
        self.inlet.setsockopt(zmq.LINGER, 0)
        self.xpub.bind(endpoint)
        self.inlet.bind(inlet)
        self.bound = self.xpub.getsockopt_string(zmq.LAST_ENDPOINT)  # tcp://localhost:N -> 127.0.0.1
        self.foreign = 0  # foreign frames since the last reset
        self.resets = 0
        self.rebind_at: float | None = None
        self.unbound_at = 0.0

    def forward(self) -> bool:
        """Move queued messages to the subscribers; False once told to stop."""
        for _ in range(BATCH):
            try:
                frames = self.inlet.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return True
            if frames == STOP:
                return False
            self.xpub.send_multipart(frames)  # an XPUB drops at a subscriber's HWM, never blocks
        return True

    def read_subscriptions(self) -> None:
        """libzmq passes up every subscription (XPUB_VERBOSE), a prefix when it leaves the trie
        (last subscriber gone), and any frame that is not a subscription. A subscription that
        receives the welcome gets it once this turn's frames are read: one welcome a turn, to
        every subscriber of ``hello`` (each ignores an id it already has), however many
        subscribers came."""
        welcome = False
        try:
            for _ in range(BATCH):
                try:
                    frame = self.xpub.recv(zmq.NOBLOCK)
                except zmq.Again:
                    return
                if frame[:1] == b"\x01" and is_known_prefix(frame[1:]):
                    welcome = welcome or WELCOME.startswith(frame[1:])
                    continue
                if frame[:1] == b"\x00":
                    continue  # a prefix leaving the trie
                self.foreign += 1
                if self.foreign > SUBSCRIPTION_BUDGET and self.rebind_at is None:
                    self.drop_subscribers()
        finally:
            if welcome and self.rebind_at is None:
                self.xpub.send(self.welcome)

    def drop_subscribers(self) -> None:
        """Unbinding closes every connection accepted on the endpoint, and with them their
        subscriptions; bind again once the listener has let go of the address."""
        self.resets += 1
        if self.resets & (self.resets - 1) == 0:  # 1, 2, 4, ...: a flood does not flood the log
            log.warning("%d subscriptions to no topic or non-subscription frames: dropping every subscriber "
                        "connection (%d times so far); they reconnect", self.foreign, self.resets)
        try:
            self.xpub.unbind(self.bound)
        except zmq.ZMQError as exc:  # ending the process drops them too: the daemon starts another
            log.error("cannot unbind %s (%s): ending the outlet instead", self.bound, exc)
            raise SystemExit(3) from exc
        self.rebind_at = self.unbound_at = time.monotonic()

    def rebind(self) -> None:
        try:
            self.xpub.bind(self.bound)
        except zmq.ZMQError as exc:  # the old listener closes in libzmq's I/O thread: soon
            if time.monotonic() - self.unbound_at > REBIND_GIVE_UP_S:  # someone else took the address
                log.error("cannot bind %s again: %s", self.bound, exc)
                raise SystemExit(3) from exc
            self.rebind_at = time.monotonic() + REBIND_RETRY_S
            return
        self.rebind_at = None
        self.foreign = 0

    def run(self, parent_pid: int) -> int:
        poller = zmq.Poller()
        poller.register(self.inlet, zmq.POLLIN)
        poller.register(self.xpub, zmq.POLLIN)
        while True:
            timeout_ms = 500 if self.rebind_at is None else int(REBIND_RETRY_S * 1000)
            ready = dict(poller.poll(timeout_ms))
            if self.xpub in ready:
                self.read_subscriptions()
            if self.inlet in ready and not self.forward():
                return 0
            if self.rebind_at is not None and time.monotonic() >= self.rebind_at:
                self.rebind()
            if os.getppid() != parent_pid:  # the daemon is gone (we were re-parented)
                return 0


def _die_with_parent() -> None:
    try:
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):  # not Linux: the parent check in the loop does it
        pass


def _cap_memory(extra_mb: float) -> None:
    """Allow this much data beyond what the process holds now (stacks and the Python
    runtime included); past it allocations fail and libzmq aborts."""
    with open("/proc/self/status") as f:
        data_kb = next(int(line.split()[1]) for line in f if line.startswith("VmData:"))
    limit = (data_kb * 1024) + int(extra_mb * 2**20)
    resource.setrlimit(resource.RLIMIT_DATA, (limit, resource.getrlimit(resource.RLIMIT_DATA)[1]))
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))  # an abort leaves no core file of a flood


def main(args: dict[str, Any]) -> int:
    _die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C reaches the group: the daemon stops us
    logging.basicConfig(level=args.get("log_level", "INFO"), format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
                        stream=sys.stderr)
    ctx = zmq.Context()
    try:
        outlet = Outlet(ctx, args["endpoint"], args["inlet"], args["hwm"], args.get("instance", ""))
    except zmq.ZMQError as exc:
        print(f"error {exc.errno} {exc}", flush=True)
        return 2
    _cap_memory(args["memory_cap_mb"])
    print("ok", flush=True)
    try:
        return outlet.run(args["parent_pid"])
    finally:
        outlet.inlet.close()
        outlet.xpub.close()
        ctx.term()


if __name__ == "__main__":  # pragma: no cover - run as a process
    sys.exit(main(json.loads(sys.argv[1])))
