"""The live view's sink: hands every sample block and event, encoded as the recording
encodes them, to the live process (controller/telemetry/live_bridge.py) that serves them
to Foxglove.

What this costs the sample loop: one JSON encoding per block or event and a non-blocking
PUSH over ipc. When the live process falls ``queue`` messages behind (it died, or the
machine is starved) messages are dropped and counted, never waited for. A live process
that ends is not started again: the live view is a convenience, control goes on and the
loss is logged.
"""

from __future__ import annotations

import json
import logging
import os
import select
import shutil
import subprocess
import sys
import time
from typing import Any

import zmq
from fluidsense.common.errors import ConfigError
from fluidsense.common.rundirs import private_dir
from fluidsense.common.samples import SampleBlock
from fluidsense.drivers.recording.messages import block_payload, to_json
from fluidsense.drivers.recording.schema import SAMPLES

from ..config import LiveConfig
from .fanout import Sink
from .live_bridge import STOP, T0

log = logging.getLogger(__name__)

DIR_PREFIX = "fluidsense-live-"  # the inlet's folder: <temp>/DIR_PREFIX<pid>-XXXXXXXX
START_TIMEOUT_S = 30.0
STOP_TIMEOUT_S = 3.0


def parse_listen(text: str, default_host: str = "127.0.0.1") -> tuple[str, int]:
    """``[HOST:]PORT`` -> (host, port); ValueError says what is wrong."""
    host, colon, port = text.rpartition(":")
    host = host.strip("[]") if colon else default_host
    if not (port.isascii() and port.isdigit() and 1 <= int(port) <= 65535):
        raise ValueError(f"{text!r}: expected [HOST:]PORT with a port in 1..65535")
    if colon and not host:
        raise ValueError(f"{text!r}: no host before the colon")
    return host, int(port)


class LiveSink(Sink):
    """Starts the live process and returns once it serves; raises ConfigError naming
    ``live`` when it cannot (the port is taken, the address is not ours)."""

    def __init__(self, cfg: LiveConfig, t0_unix_ns: int | None = None):
        self.cfg = cfg
        self.t0_unix_ns = time.time_ns() if t0_unix_ns is None else t0_unix_ns
        self.dropped = 0
        self.sent = 0
        self._said_dead = False
        self._closed = False
        self._dir = str(private_dir(DIR_PREFIX))  # 0700: only our user
        inlet = f"ipc://{self._dir}/inlet"
        args = {"host": cfg.host, "port": cfg.port, "backlog": cfg.backlog, "inlet": inlet,
                "t0_unix_ns": self.t0_unix_ns, "parent_pid": os.getpid(),
                "log_level": logging.getLevelName(log.getEffectiveLevel())}
        self._proc = subprocess.Popen([sys.executable, "-m", "fluidsense.controller.telemetry.live_bridge", json.dumps(args)],
                                      stdin=subprocess.DEVNULL, stdout=subprocess.PIPE)
        try:
            self.port = self._wait_ready()
        except BaseException:
            self._kill()
            shutil.rmtree(self._dir, ignore_errors=True)
            raise
        self._ctx = zmq.Context.instance()
        self._push = self._ctx.socket(zmq.PUSH)
        self._push.setsockopt(zmq.SNDHWM, cfg.queue)
        self._push.setsockopt(zmq.LINGER, int(STOP_TIMEOUT_S * 1000))
        self._push.connect(inlet)
        log.info("live view (Foxglove WebSocket) on ws://%s:%d (process %d)", cfg.host, self.port, self._proc.pid)

    @property
    def url(self) -> str:
        return f"ws://{self.cfg.host}:{self.port}"

    def _wait_ready(self) -> int:
        ready = select.select([self._proc.stdout], [], [], START_TIMEOUT_S)[0]
        said = self._proc.stdout.readline().decode(errors="replace").strip() if ready else ""
        self._proc.stdout.close()
        if said.startswith("ok "):
            return int(said.split()[1])
        reason = said.removeprefix("error ") or "the live process did not start"
        raise ConfigError(f"live: cannot serve on {self.cfg.host}:{self.cfg.port}: {reason}")

    def set_t0(self, t0_unix_ns: int) -> None:
        """Take the recording's wall clock at sample time 0 (known once it has started)."""
        self.t0_unix_ns = t0_unix_ns
        self._send(T0, 0.0, str(int(t0_unix_ns)).encode())

    # ------------------------------------------------------------ Sink
    def on_block(self, block: SampleBlock) -> None:
        self._send(SAMPLES, block.t_end, to_json(block_payload(block)))

    def on_event(self, topic: str, t_s: float, payload: dict[str, Any]) -> None:
        self._send(topic, t_s, to_json({"t_s": t_s, **payload}))
        if topic == "heartbeat":
            self._look_after()

    def _send(self, topic: str, t_s: float, data: bytes) -> None:
        try:
            self._push.send_multipart([topic.encode("ascii"), repr(float(t_s)).encode(), data], flags=zmq.NOBLOCK)
            self.sent += 1
        except zmq.Again:
            self.dropped += 1
            if self.dropped & (self.dropped - 1) == 0:  # 1, 2, 4, ...: a stalled view does not flood the log
                log.warning("live view: %d messages dropped so far (the live process is %d behind)",
                            self.dropped, self.cfg.queue)

    def _look_after(self) -> None:
        if self._proc.poll() is not None and not self._said_dead:
            self._said_dead = True
            log.error("live view: its process ended (exit code %s); control goes on without it",
                      self._proc.returncode)

    def close(self) -> None:
        """The queued messages go out (bounded by LINGER), then the live process ends.
        Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        try:
            if self._proc.poll() is None:
                self._push.send_multipart(STOP, flags=zmq.NOBLOCK)
                self._proc.wait(STOP_TIMEOUT_S)
        except (zmq.Again, subprocess.TimeoutExpired):
            pass
        finally:
            self._push.close(linger=0)
            self._kill()
            shutil.rmtree(self._dir, ignore_errors=True)
            if self.dropped:
                log.warning("live view closed: %d of %d messages dropped", self.dropped, self.sent + self.dropped)

    def _kill(self) -> None:
        if self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()
