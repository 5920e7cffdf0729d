"""ZeroMQ PUB side of the published interface (schema in docs/zmq-schema.md).

Every message is two frames: the topic (ASCII) and a JSON object that always carries
``schema`` (the schema version), ``instance`` (this daemon's id, random per start: a
subscriber tells a restarted daemon on the same ports by it), ``topic``, ``seq`` (one counter over all topics, so a
subscriber to everything sees gaps), ``topic_seq`` (one counter per topic, so a subscriber
to some topics sees its gaps), ``t_s`` (sample time of the newest sample when it was
sent) and ``utc_s`` (wall-clock UTC when it was sent, to line messages up with other logs).
A slow subscriber never blocks the controller: PUB drops at its high-water mark.

The public XPUB socket lives in an outlet process (controller/telemetry/outlet.py): subscriptions
are untrusted input that libzmq can spend unbounded time and memory on, and there they
cost the daemon nothing. The daemon PUSHes each encoded message to the outlet over ipc
in a directory only its user can enter, never blocking: when the outlet falls behind by
``hwm`` messages, messages are dropped and counted. An outlet that dies is started again.

The socket has a welcome message: a subscriber that subscribes to ``hello`` receives the
single frame ``hello INSTANCE`` as soon as it is connected, so it knows that nothing published
after that is lost to the usual ZeroMQ slow-joiner gap.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import os
import secrets
import select
import shutil
import subprocess
import sys
import time
from typing import Any

import numpy as np
import zmq
from fluidsense.common.names import INSTANCE_HEX, TOPICS, WELCOME
from fluidsense.common.rundirs import private_dir
from fluidsense.controller.telemetry.outlet import STOP

log = logging.getLogger(__name__)

SCHEMA_VERSION = 2  # 2: ``instance`` in every message and in the welcome
START_TIMEOUT_S = 30.0
STOP_TIMEOUT_S = 3.0  # the outlet lingers up to a second for the last messages
CHECK_PERIOD_S = 0.2  # how often send() looks whether the outlet is still there
RESTART_BACKOFF_S = (0.0, 0.5, 2.0, 5.0)
STABLE_S = 10.0  # an outlet up this long has its restart back-off forgotten
# data the outlet may hold beyond its start: a few slow subscribers' queues (10,000
# messages of about 2.5 kB each) fit; a flood of subscriptions ends it
OUTLET_MEMORY_CAP_MB = 256.0
DIR_PREFIX = "fluidsense-pub-"

__all__ = ["SCHEMA_VERSION", "TOPICS", "WELCOME", "Publisher", "NullPublisher", "encode", "new_instance"]


def new_instance() -> str:
    """A daemon instance's id: random, so that two starts on the same ports never share one
    (cycle ids and sequence numbers start again at 1 after a restart)."""
    return secrets.token_hex(INSTANCE_HEX // 2)


def _default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def _clean(obj: Any) -> Any:
    """JSON has no NaN/inf: they become null."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    return obj


def encode(topic: str, seq: int, t_s: float, payload: dict[str, Any], topic_seq: int = 0,
           utc_s: float | None = None, instance: str = "") -> list[bytes]:
    msg = {"schema": SCHEMA_VERSION, "instance": instance, "topic": topic, "seq": seq, "topic_seq": topic_seq or seq, "t_s": t_s,
           "utc_s": time.time() if utc_s is None else utc_s, **payload}
    return [topic.encode("ascii"), json.dumps(_clean(msg), default=_default, allow_nan=False).encode()]


class Publisher:
    publishes = True  # pressure batches are built for it (NullPublisher: not)

    def __init__(self, endpoint: str, context: zmq.Context | None = None, hwm: int = 10_000,
                 instance: str | None = None):
        """Starts the outlet and returns once ``endpoint`` is bound; raises zmq.ZMQError
        when it cannot be. ``instance``: the daemon's id (a new one if None)."""
        self.endpoint = endpoint
        self.instance = instance or new_instance()
        self.seq = 0
        self.topic_seq: dict[str, int] = {}
        self.dropped = 0  # messages that never reached the outlet
        self.restarts = 0
        self._hwm = hwm
        # 0700: only our user reaches the inlet; the pid in the name lets a later daemon
        # remove it if this one is killed before it can
        self._dir = str(private_dir(DIR_PREFIX))
        self._inlet = f"ipc://{self._dir}/inlet"
        self._proc: subprocess.Popen | None = None
        self._next_check = 0.0
        self._failures = 0
        self._restart_at: float | None = None
        self._started_at = 0.0
        try:
            self._start(wait=True)
        except BaseException:
            shutil.rmtree(self._dir, ignore_errors=True)
            raise
        ctx = context or zmq.Context.instance()
        self._push = ctx.socket(zmq.PUSH)
        self._push.setsockopt(zmq.SNDHWM, max(hwm, 10_000))
        self._push.setsockopt(zmq.LINGER, int(STOP_TIMEOUT_S * 1000))
        self._push.connect(self._inlet)
        self._timer: asyncio.TimerHandle | None = None
        try:  # an idle daemon sends nothing: look after the outlet on a timer too
            self._loop: asyncio.AbstractEventLoop | None = asyncio.get_running_loop()
        except RuntimeError:
            self._loop = None
        self._tick()
        log.info("publishing on %s (outlet process %d)", endpoint, self._proc.pid)

    def _tick(self) -> None:
        self._check_outlet()
        if self._loop is not None:
            self._timer = self._loop.call_later(CHECK_PERIOD_S, self._tick)

    @property
    def stats(self) -> dict[str, int]:
        return {"dropped": self.dropped, "outlet_restarts": self.restarts}

    def _start(self, wait: bool) -> None:
        args = {"endpoint": self.endpoint, "inlet": self._inlet, "instance": self.instance, "hwm": self._hwm, "parent_pid": os.getpid(),
                "memory_cap_mb": OUTLET_MEMORY_CAP_MB, "log_level": logging.getLevelName(log.getEffectiveLevel())}
        self._proc = subprocess.Popen([sys.executable, "-m", "fluidsense.controller.telemetry.outlet", json.dumps(args)],
                                      stdin=subprocess.DEVNULL, stdout=subprocess.PIPE if wait else subprocess.DEVNULL)
        self._started_at = time.monotonic()
        if not wait:
            return
        ready = select.select([self._proc.stdout], [], [], START_TIMEOUT_S)[0]
        said = self._proc.stdout.readline().decode().strip() if ready else ""
        self._proc.stdout.close()
        if said == "ok":
            return
        self._kill()
        if said.startswith("error "):
            _, errno, message = said.split(" ", 2)
            raise zmq.ZMQError(int(errno), message)
        raise zmq.ZMQError(msg=f"the publisher's outlet process did not start (said {said!r})")

    def _kill(self) -> None:
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()

    def _check_outlet(self) -> None:
        """An outlet that ended (a flood of subscriptions hit its memory cap) is started
        again, at once the first time, then backing off; the queue to it keeps what it had
        not taken."""
        now = time.monotonic()
        if now < self._next_check:
            return
        self._next_check = now + CHECK_PERIOD_S
        if self._proc.poll() is None:
            if now - self._started_at > STABLE_S:
                self._failures = 0
            return
        if self._restart_at is None:
            delay = RESTART_BACKOFF_S[min(self._failures, len(RESTART_BACKOFF_S) - 1)]
            self._failures += 1
            self.restarts += 1
            self._restart_at = now + delay
            log.warning("publisher outlet ended (exit code %s): starting another in %.1f s",
                        self._proc.returncode, delay)
        if now >= self._restart_at:
            self._restart_at = None
            self._start(wait=False)

    def send(self, topic: str, t_s: float, payload: dict[str, Any]) -> None:
        self.seq += 1
        self.topic_seq[topic] = self.topic_seq.get(topic, 0) + 1
        try:
            self._push.send_multipart(encode(topic, self.seq, t_s, payload, self.topic_seq[topic],
                                             instance=self.instance), flags=zmq.NOBLOCK)
        except zmq.Again:
            self.dropped += 1
        self._check_outlet()

    def close(self) -> None:
        """The messages sent so far go out (the outlet lingers a second for slow
        subscribers), then the outlet ends."""
        if self._timer is not None:
            self._timer.cancel()
        try:
            self._push.send_multipart(STOP, flags=zmq.NOBLOCK)
            self._proc.wait(STOP_TIMEOUT_S)
        except (zmq.Again, subprocess.TimeoutExpired):
            log.warning("publisher outlet did not stop in %.0f s: killed", STOP_TIMEOUT_S)
        finally:
            self._kill()
            self._push.close(linger=0)
            shutil.rmtree(self._dir, ignore_errors=True)


class NullPublisher:
    """Used when nothing is published (demo, benchmarks): same interface, no socket."""

    endpoint = None
    #: nobody can hear a pressure batch: the telemetry does not build them (in virtual
    #: time, studies and calibrations, that was about a tenth of a block's cost)
    publishes = False

    def __init__(self) -> None:
        self.seq = 0
        self.dropped = 0
        self.instance = new_instance()

    @property
    def stats(self) -> dict[str, int]:
        return {"dropped": 0, "outlet_restarts": 0}

    def send(self, topic: str, t_s: float, payload: dict[str, Any]) -> None:
        self.seq += 1

    def close(self) -> None:
        return None
