"""The live view's process: ``python -m fluidsense.controller.telemetry.live_bridge ARGS_JSON``.

It serves the Foxglove WebSocket protocol (foxglove-sdk, behind live_front.py, which lets
in both its names: ``foxglove.sdk.v1`` and ``foxglove.websocket.v1``) with the channels, JSON schemas
and log times of the MCAP recordings (drivers/recording/), so that a recorded file and
the live daemon look the same in Foxglove. It runs apart from the daemon for the same
reason as the publisher's outlet: viewers are untrusted peers, and however many or slow
they are they cost the sample loop nothing but a non-blocking PUSH. The SDK queues at most
``backlog`` messages per viewer and drops the oldest beyond it.

ARGS_JSON: ``host``, ``port``, ``backlog``, ``inlet`` (ipc endpoint bound here, in a
directory only the daemon's user can enter), ``t0_unix_ns`` (the wall clock at sample time
0: the recording's), ``parent_pid``. Prints ``ok PORT`` once serving, or ``error MESSAGE``.
Each inlet message is three frames: topic, sample time (ASCII float), the JSON payload as
the recording writes it. A single-frame ``stop`` ends it.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import sys
from typing import Any

import zmq
from fluidsense.drivers.recording.schema import SAMPLES, event_schema

log = logging.getLogger("fluidsense.controller.telemetry.live_bridge")

# the recording's channels (every event the controller emits, and the sample blocks),
# advertised from the start so that a viewer sees them before the first message
LIVE_TOPICS = (SAMPLES, "state", "cycle", "fault", "task", "heartbeat", "cycle_start", "command")
STOP = [b"stop"]
T0 = "t0"  # a message that sets t0_unix_ns (the recording's, once the daemon knows it)
MAX_MESSAGE_BYTES = 16 * 2**20
BATCH = 1000


def log_time_ns(t0_ns: int, t_s: float) -> int:
    """The recording's log time: wall clock at sample time 0 plus sample time."""
    return t0_ns + max(0, round(t_s * 1e9))


class Bridge:
    def __init__(self, args: dict[str, Any]):
        import foxglove  # the process's one reason to exist: imported only here

        from .live_front import Front

        self.t0_ns = int(args["t0_unix_ns"])
        self.fx = foxglove.Context()
        # the SDK on a loopback port of its own; the front on the configured address lets in
        # the protocol's old name too (Lichtblick, older Foxglove: live_front.py)
        self.server = foxglove.start_server(name="fluidsense", host="127.0.0.1", port=0,
                                            context=self.fx, message_backlog_size=args["backlog"])
        try:
            self.front = Front(args["host"], args["port"], self.server.port)
        except BaseException:
            self.server.stop()
            raise
        self.channels = {}
        for topic in LIVE_TOPICS:
            schema = event_schema(topic)
            self.channels[topic] = foxglove.Channel(
                "/" + topic, message_encoding="json", context=self.fx,
                schema=foxglove.Schema(name=schema.get("title", topic), encoding="jsonschema",
                                       data=json.dumps(schema).encode()))
        self.zctx = zmq.Context()
        self.inlet = self.zctx.socket(zmq.PULL)
        self.inlet.setsockopt(zmq.MAXMSGSIZE, MAX_MESSAGE_BYTES)
        self.inlet.setsockopt(zmq.LINGER, 0)
        self.inlet.bind(args["inlet"])
        self.unknown = 0

    def forward(self) -> bool:
        """Hand queued messages to the viewers; False once told to stop."""
        for _ in range(BATCH):
            try:
                frames = self.inlet.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return True
            if frames == STOP:
                return False
            if len(frames) != 3:
                continue
            if frames[0] == T0.encode():
                self.t0_ns = int(frames[2])
                continue
            channel = self.channels.get(frames[0].decode("ascii", "replace"))
            if channel is None:  # a topic only the publisher knows ("log"): not in recordings either
                self.unknown += 1
                continue
            if channel.has_sinks():  # nobody watching: nothing to encode or queue
                channel.log(frames[2], log_time=log_time_ns(self.t0_ns, float(frames[1])))
        return True

    def run(self, parent_pid: int) -> int:
        while True:
            if self.inlet.poll(500) and not self.forward():
                return 0
            if os.getppid() != parent_pid:  # the daemon is gone (we were re-parented)
                return 0

    def close(self) -> None:
        self.front.close()
        self.server.stop()
        self.inlet.close()
        self.zctx.term()


def main(args: dict[str, Any]) -> int:
    from .outlet import _die_with_parent

    _die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C reaches the group: the daemon stops us
    logging.basicConfig(level=args.get("log_level", "INFO"), stream=sys.stderr,
                        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s")
    try:
        bridge = Bridge(args)
    except Exception as exc:  # noqa: BLE001 - the SDK raises its own types for a busy port
        print("error " + " ".join(f"{type(exc).__name__}: {exc}".split()), flush=True)
        return 2
    print(f"ok {bridge.front.port}", flush=True)
    try:
        return bridge.run(args["parent_pid"])
    finally:
        bridge.close()


if __name__ == "__main__":  # pragma: no cover - run as a process
    sys.exit(main(json.loads(sys.argv[1])))
