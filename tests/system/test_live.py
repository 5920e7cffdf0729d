"""The live view: a real daemon serving the Foxglove WebSocket protocol (foxglove-sdk) to
real WebSocket clients (the websockets library) over loopback. Nothing is mocked.

(Its in-process tests: tests/unit/test_live.py.)
"""

from __future__ import annotations

import contextlib
import json
import socket
import struct

import numpy as np
import pytest
from fluidsense.controller.telemetry.live_bridge import LIVE_TOPICS
from fluidsense.drivers.recording.schema import event_schema
from support.harness import Daemon, free_tcp_port, sim_config
from websockets.sync.client import connect

SUBPROTOCOL = "foxglove.sdk.v1"
LEGACY = "foxglove.websocket.v1"  # the same protocol's name before the SDK: Lichtblick, older Foxglove
MESSAGE_DATA = 0x01


class Viewer:
    """A Foxglove WebSocket client: reads the advertisement, subscribes by topic."""

    def __init__(self, port: int, stack: contextlib.ExitStack, subprotocol: str = SUBPROTOCOL):
        self.ws = stack.enter_context(connect(f"ws://127.0.0.1:{port}", subprotocols=[subprotocol], open_timeout=30,
                                                 close_timeout=1))  # unread data waits before its close
        assert self.ws.subprotocol == subprotocol
        self.channels: dict[str, dict] = {}
        self.subs: dict[int, str] = {}
        while len(self.channels) < len(LIVE_TOPICS):
            msg = self.ws.recv(timeout=30)
            if isinstance(msg, str):
                op = json.loads(msg)
                if op["op"] == "advertise":
                    self.channels.update({c["topic"]: c for c in op["channels"]})

    def subscribe(self, *topics: str) -> None:
        subs = [{"id": 100 + i, "channelId": self.channels["/" + t]["id"]} for i, t in enumerate(topics)]
        self.subs.update({s["id"]: t for s, t in zip(subs, topics)})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def next_data(self, timeout_s: float = 30.0) -> tuple[str, int, dict]:
        while True:
            msg = self.ws.recv(timeout=timeout_s)
            if isinstance(msg, bytes) and msg[0] == MESSAGE_DATA:
                sub, log_time = struct.unpack_from("<IQ", msg, 1)
                return self.subs[sub], log_time, json.loads(msg[13:])


def live_daemon(tmp_path, **live) -> tuple[Daemon, int]:
    port = free_tcp_port()
    return Daemon(sim_config(tmp_path, clock="realtime", live={"enabled": True, "port": port, **live})), port


def test_viewers_see_the_recordings_channels_and_the_published_samples(tmp_path):
    daemon, port = live_daemon(tmp_path)
    stack = contextlib.ExitStack()
    try:
        daemon.wait_welcome()
        # two speak the protocol's SDK name, two its old one (Lichtblick's): all are served alike
        viewers = [Viewer(port, stack, name) for name in (SUBPROTOCOL, LEGACY, SUBPROTOCOL, LEGACY)]
        for v in viewers:  # the recording's channels, with its JSON schemas
            assert set(v.channels) == {"/" + t for t in LIVE_TOPICS}
            for topic in LIVE_TOPICS:
                ch = v.channels["/" + topic]
                assert ch["encoding"] == "json" and ch["schemaEncoding"] == "jsonschema"
                assert json.loads(ch["schema"]) == event_schema(topic)
            v.subscribe("samples", "heartbeat")
        first = viewers[0]
        # the same samples ZeroMQ publishes (kPa there, Pa here): collect a run of blocks
        # live, then find each of them in the published batches
        blocks = {}
        while len(blocks) < 50:
            topic, log_time, data = first.next_data()
            if topic == "samples":
                assert log_time > 0 and set(data) == {"seq", "times_s", "channels", "values", "missed", "late"}
                blocks[data["seq"]] = data
        published: dict[float, list[float]] = {}
        last_t = max(max(b["times_s"]) for b in blocks.values())
        while not published or max(published) < last_t:
            _, msg = daemon.next_message("pressure")
            for i, t in enumerate(msg["times_s"]):
                published[t] = [row[i] for row in msg["values"]]
        compared = 0
        for b in blocks.values():
            for i, t in enumerate(b["times_s"]):
                if t in published:
                    live_kpa = [row[i] / 1e3 for row in b["values"]]
                    assert np.allclose(live_kpa, published[t], atol=1e-5), (t, live_kpa, published[t])
                    compared += 1
        assert compared >= 100  # the subscriber connected before the viewer: most samples overlap
        seqs = sorted(blocks)
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), "a viewer lost blocks"
        # with 4 viewers attached the 1 kHz loop loses nothing: the daemon's own count
        while True:
            _, hb = daemon.next_message("heartbeat")
            if hb["samples"] > 2000:
                break
        assert hb["missed"] == 0, hb
        for v in viewers[1:]:  # every viewer is served, not only the first
            assert v.next_data()[0] in ("samples", "heartbeat")
    finally:
        stack.close()
        rc = daemon.close()
    err = daemon.stderr_now()
    assert rc == 0, err
    assert "Traceback" not in err, err
    assert f"ws://127.0.0.1:{port}" in err


def test_a_taken_port_is_refused_before_anything_starts(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        daemon = Daemon(sim_config(tmp_path, clock="realtime", live={"enabled": True, "port": s.getsockname()[1]}))
        rc = daemon.proc.wait(60)
        err = daemon.proc.stderr.read().decode()
        daemon.close()
    assert rc == 2, err
    assert "live: cannot serve on 127.0.0.1:" in err and "Traceback" not in err, err
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())  # nothing started


def test_lichtblicks_protocol_name_is_served_and_an_unknown_one_refused(tmp_path):
    """A real websocket client speaking ``foxglove.websocket.v1`` gets the advertisement and
    data (it used to get HTTP 400); one speaking neither name still gets 400."""
    from websockets.exceptions import InvalidStatus

    daemon, port = live_daemon(tmp_path)
    stack = contextlib.ExitStack()
    try:
        daemon.wait_welcome()
        old = Viewer(port, stack, LEGACY)
        assert set(old.channels) == {"/" + t for t in LIVE_TOPICS}
        old.subscribe("heartbeat")
        topic, log_time, data = old.next_data()
        assert topic == "heartbeat" and log_time > 0 and data["samples"] > 0
        with pytest.raises(InvalidStatus) as refused:
            connect(f"ws://127.0.0.1:{port}", subprotocols=["other.v1"], open_timeout=30)
        assert refused.value.response.status_code == 400
    finally:
        stack.close()
        rc = daemon.close()
    err = daemon.stderr_now()
    assert rc == 0 and "Traceback" not in err, err
