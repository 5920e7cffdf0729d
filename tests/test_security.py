"""Bad input and exposure: a fuzzed command socket, CURVE off loopback."""

from __future__ import annotations

import json
import socket
import subprocess
import sys

import pytest
import yaml
import zmq
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from controller.config import load_cell_config
from drivers.errors import ConfigError

from .conftest import REPO, sim_config

COMMANDS = ["status", "cycle", "abort", "reset", "scene", "task"]  # not shutdown: it would end the run
json_values = st.recursive(st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=20),
                           lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner,
                                                                                        max_size=4), max_leaves=10)
requests = st.one_of(
    st.binary(max_size=300).map(lambda b: [b]),
    json_values.map(lambda v: [json.dumps(v).encode()]),
    st.fixed_dictionaries({"cmd": st.sampled_from(COMMANDS + ["", "stat", "SHUTDOWN", "cycles"])},
                          optional={"p0_kpa": json_values, "label": json_values, "scene": json_values,
                                    "file": json_values, "reason": json_values, "extra": json_values,
                                    "store_reference": json_values}).map(lambda d: [json.dumps(d).encode()]),
    st.lists(st.binary(max_size=20), min_size=2, max_size=4),
)


@pytest.fixture(scope="module")
def fuzz_target(tmp_path_factory, request):
    from .conftest import Daemon

    tmp = tmp_path_factory.mktemp("fuzz")
    d = Daemon(sim_config(tmp, clock="realtime"))
    d.wait_welcome()
    ctx = zmq.Context()
    sock = ctx.socket(zmq.REQ)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(d.cmd)
    yield d, sock
    sock.close()
    ctx.term()
    d.close()


COUNT = {"n": 0, "errors": 0}


@settings(max_examples=10_000, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(frames=requests)
def test_fuzzed_command_socket_answers_everything(fuzz_target, frames):
    d, sock = fuzz_target
    sock.send_multipart(frames)
    assert sock.poll(10_000), f"no reply to {frames!r}"
    reply = json.loads(sock.recv())
    assert isinstance(reply, dict) and isinstance(reply["ok"], bool)
    if not reply["ok"]:
        assert isinstance(reply["error"], str) and reply["error"]
        COUNT["errors"] += 1
    COUNT["n"] += 1


def test_after_fuzzing_the_daemon_runs_and_its_loop_never_stalled(fuzz_target):
    d, sock = fuzz_target
    assert COUNT["n"] >= 10_000 and COUNT["errors"] > COUNT["n"] // 2
    assert d.proc.poll() is None
    before = d.request({"cmd": "status"})
    beat = {"samples": -1}
    while beat["samples"] <= before["samples"]:  # a heartbeat sent after the status: still sampling
        _, beat = d.next_message("heartbeat", timeout_s=10)
    after = d.request({"cmd": "status"})
    # an overrun (the loop falling behind its samples) would have latched a fault
    assert after["fault"] is None or after["fault"]["kind"] != "overrun", after["fault"]
    assert beat["missed"] == 0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("0.0.0.0", 0))
        return s.getsockname()[1]


def test_a_command_socket_off_loopback_needs_curve_keys(tmp_path):
    path = sim_config(tmp_path, endpoints=(f"ipc://{tmp_path}/pub", f"tcp://0.0.0.0:{_free_port()}"))
    with pytest.raises(ConfigError, match=r"publisher: .*not loopback.*cmd_curve"):
        load_cell_config(path)


def test_curve_lets_in_known_clients_only(tmp_path, daemon_factory):
    keys = tmp_path / "keys"
    out = subprocess.run([sys.executable, "-m", "fluidsense.cli", "keys", str(keys)], cwd=REPO,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    port = _free_port()
    path = sim_config(tmp_path, endpoints=(f"ipc://{tmp_path}/pub", f"tcp://0.0.0.0:{port}"))
    data = yaml.safe_load(path.read_text())
    data["publisher"]["cmd_curve"] = {"server_secret_file": str(keys / "server.key_secret"),
                                      "clients_dir": str(keys / "clients")}
    path.write_text(yaml.safe_dump(data))
    d = daemon_factory(path)
    d.wait_welcome()
    endpoint = f"tcp://127.0.0.1:{port}"
    from fluidsense.monitor import send_command

    ok = send_command(endpoint, {"cmd": "status"}, 10.0,
                      curve=(str(keys / "client.key_secret"), str(keys / "server.key")))
    assert ok["ok"] and ok["state"] == "idle"
    with pytest.raises(TimeoutError):  # no keys: the handshake never completes, no reply
        send_command(endpoint, {"cmd": "status"}, 2.0)
