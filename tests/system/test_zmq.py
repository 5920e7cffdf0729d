"""`fluidsense run` over real ZeroMQ sockets, checked against docs/zmq-schema.md.

The subscriber here is written against the document: the JSON schemas are read out of
docs/zmq-schema.md, not from the code.

(Its in-process tests: tests/unit/test_zmq.py.)
"""

from __future__ import annotations

import os
import signal

import pytest
import zmq
from support.events import check, fast_profile
from support.harness import REPO, sim_config
from support.requests import BAD_REQUESTS
from fluidsense.common.names import welcome_instance


def test_every_message_of_a_sorting_task_is_documented(tmp_path, daemon_factory):
    """A full sorting task through the daemon: every message validates against its schema
    (no undocumented field), per-topic counters have no gap, every message has its UTC time."""
    from support.harness import CONFIG

    # the quick protocol (0.5 s window, not 5 s): the same messages, a third of the cycle time
    d = daemon_factory(sim_config(tmp_path, profile=str(CONFIG / "profiles" / "sorting-gripper-quick.yaml")))
    d.wait_welcome()
    assert d.request({"cmd": "task", "file": "sorting.yaml"})["started"]
    seen: dict[str, list] = {}
    while True:
        topic, msg = d.next_message(timeout_s=120)
        check(topic, msg)
        seen.setdefault(topic, []).append(msg)
        if topic == "task" and msg["event"] in ("finished", "failed", "aborted"):
            break
    assert msg["event"] == "finished" and msg["summary"]["success"]
    assert {"heartbeat", "state", "cycle", "pressure", "task"} <= set(seen)
    for msgs in seen.values():
        counts = [m["topic_seq"] for m in msgs]
        assert counts == list(range(counts[0], counts[0] + len(counts)))
    utc = [m["utc_s"] for msgs in seen.values() for m in sorted(msgs, key=lambda m: m["seq"])]
    assert min(utc) > 1.6e9


def collect_until_cycle(d, seen: dict) -> dict:
    while True:
        topic, msg = d.next_message()
        check(topic, msg)
        seen.setdefault(topic, []).append(msg)
        if topic == "cycle":
            return msg


def test_subscriber_receives_heartbeats_states_pressure_and_cycle_results(tmp_path, daemon_factory):
    d = daemon_factory(sim_config(tmp_path, clock="virtual"))
    d.wait_welcome()
    seen: dict[str, list] = {}
    reply = d.request({"cmd": "cycle", "store_reference": True})
    # the daemon's instance id: in its welcome, in the reply that starts a cycle, in every message
    assert reply == {"ok": True, "cycle_id": 1, "instance": d.instance} and len(d.instance) == 16
    ref = collect_until_cycle(d, seen)
    assert ref["ok"] and ref["is_reference"] and ref["p_eq_kpa"] == pytest.approx(34.6, abs=0.2)
    assert d.request({"cmd": "scene", "scene": {"kind": "cylinder", "diameter_mm": 80}})["ok"]
    assert d.request({"cmd": "cycle"})["cycle_id"] == 2
    res = collect_until_cycle(d, seen)
    assert res["has_reference"] and res["dp_eq_kpa"] > 1.5 and res["t_c_slope_s"] > 0

    # a heartbeat per second of sample time: two 50 s cycles give about 100
    beats = seen["heartbeat"]
    assert len(beats) >= 90
    assert beats[-1]["samples"] > beats[0]["samples"] and beats[-1]["missed"] == 0
    assert {m["instance"] for msgs in seen.values() for m in msgs} == {d.instance}
    # the transitions, in order, for each cycle
    states = [(m["cycle_id"], m["to"]) for m in seen["state"]]
    order = ["charge", "isolate", "actuate", "hold", "vent", "idle"]
    assert [s for c, s in states if c == 1] == order
    assert [s for c, s in states if c == 2] == order
    # one counter over all topics, no gaps after the welcome
    seqs = sorted(m["seq"] for msgs in seen.values() for m in msgs)
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))
    # every sample was published in pressure batches: contiguous, none lost or repeated
    times = [t for m in seen["pressure"] for t in m["times_s"]]
    k = [round(t * 1000) for t in times]
    assert k == list(range(k[0], k[0] + len(k)))
    assert k[0] == 0 and len(k) >= ref["samples"] + res["samples"] - 100  # the last batch may be pending

    assert d.request({"cmd": "shutdown"}) == {"ok": True, "shutting_down": True}
    assert d.proc.wait(30) == 0


def test_bad_commands_get_an_error_reply_and_the_daemon_keeps_running(tmp_path, daemon_factory):
    d = daemon_factory(sim_config(tmp_path, clock="virtual"))
    d.wait_welcome()
    for frames, reason in BAD_REQUESTS:
        reply = d.request(None, raw=frames)
        assert reply["ok"] is False, frames
        assert reason in reply["error"], (frames, reply)
    status = d.request({"cmd": "status"})
    assert status["ok"] and status["state"] == "idle" and status["fault"] is None
    assert d.proc.poll() is None
    assert d.request({"cmd": "cycle"})["ok"]
    assert d.request({"cmd": "cycle"})["error"].startswith("busy")


def test_real_time_heartbeat_and_sigterm_vents_then_exits(tmp_path, daemon_factory):
    d = daemon_factory(sim_config(tmp_path, clock="realtime", profile=fast_profile(tmp_path)))
    d.wait_welcome()
    _, beat = d.next_message("heartbeat", timeout_s=10)
    check("heartbeat", beat)
    assert beat["virtual"] is False and beat["rate_hz"] == 1000
    # the daemon asked for SCHED_FIFO (loop.rt_priority 20): granted or refused, and status says which and why
    rt = d.request({"cmd": "status"})["realtime"]
    assert beat["realtime"] == rt["sched_fifo"] in ("granted", "refused") and rt["priority"] == 20
    assert rt["detail"].startswith("SCHED_FIFO priority 20 " + ("refused" if rt["sched_fifo"] == "refused" else "("))
    assert d.request({"cmd": "cycle"})["ok"]
    d.wait_state("actuate", 30)  # in real time, the actuation valve opens: the actuator inflates
    d.proc.send_signal(signal.SIGTERM)
    tail = []
    while True:
        topic, msg = d.next_message(timeout_s=15)
        check(topic, msg)
        tail.append((topic, msg))
        if topic == "log" and msg["message"] == "controller stopped":
            break
    assert d.proc.wait(30) == 0
    assert b"stopping: venting and closing" in d.proc.stderr.read()
    # in this order: the cycle aborted into VENT, its (aborted) result, then the last message
    # saying every valve is in its safe position (actuation valve closed: the actuator vents)
    states = [m for t, m in tail if t == "state"]
    assert [(m["from"], m["to"], m["reason"]) for m in states] == [("actuate", "vent", "abort: shutdown")]
    cycles = [m for t, m in tail if t == "cycle"]
    assert len(cycles) == 1 and cycles[0]["aborted"] == "shutdown" and not cycles[0]["ok"]
    seq = {id(m): m["seq"] for _, m in tail}
    last = tail[-1][1]
    assert seq[id(states[0])] < seq[id(cycles[0])] < last["seq"]
    assert last["safe"] is True and last["valves"] and not any(last["valves"].values())


def test_monitor_shows_transitions_and_the_result(tmp_path, daemon_factory):
    import subprocess
    import sys

    d = daemon_factory(sim_config(tmp_path, clock="virtual"))
    d.wait_welcome()
    mon = subprocess.Popen([sys.executable, "-m", "fluidsense", "monitor", "--endpoint", d.pub,
                            "--topic", "state", "--topic", "cycle", "--count", "7", "--timeout", "30"],
                           cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert "(connected to" in mon.stderr.readline()  # its subscription is attached
        assert d.request({"cmd": "cycle"})["ok"]
        out, _ = mon.communicate(timeout=60)
    finally:
        mon.kill()
    lines = out.strip().splitlines()
    assert mon.returncode == 0 and len(lines) == 7
    assert "idle -> charge" in lines[0] and "vent -> idle" in lines[5]
    assert lines[6].startswith("[") and "cycle 1: P_eq 34." in lines[6]


# ---------------------------------------------------------------- hostile subscribers
def _status_kb(pid: int, field: str) -> int:
    with open(f"/proc/{pid}/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith(f"{field}:"))


def _outlets(d) -> list[int]:
    """The daemon's child processes: its publisher outlet (the simulated cell has no sampler)."""
    with open(f"/proc/{d.proc.pid}/task/{d.proc.pid}/children") as f:
        return [int(pid) for pid in f.read().split()]


def _topics_until_heartbeats(sock, n: int = 2) -> set[str]:
    seen, beats = set(), 0
    while beats < n:
        assert sock.poll(30_000), f"no heartbeat; saw {seen}"
        frames = sock.recv_multipart()
        if len(frames) == 2:
            seen.add(frames[0].decode())
            beats += frames[0] == b"heartbeat"
    return seen


def _subscriber(d, *prefixes: bytes):
    sock = d.ctx.socket(zmq.SUB)
    sock.setsockopt(zmq.LINGER, 0)
    for prefix in (*prefixes, b"hello"):
        sock.setsockopt(zmq.SUBSCRIBE, prefix)
    sock.connect(d.pub)
    assert sock.poll(30_000) and welcome_instance(sock.recv_multipart())
    return sock


def test_a_subscription_gets_the_topics_that_start_with_it(tmp_path, daemon_factory):
    """The documented rule: ZeroMQ's prefix match on the topic frame."""
    d = daemon_factory(sim_config(tmp_path, clock="realtime"))
    d.wait_welcome()
    prefixed = _subscriber(d, b"pre", b"heart")
    longer = _subscriber(d, b"pressure.v2", b"heartbeat")  # longer than any topic: matches none
    assert _topics_until_heartbeats(prefixed) == {"pressure", "heartbeat"}
    assert _topics_until_heartbeats(longer) == {"heartbeat"}  # ten pressure batches a second went elsewhere
    prefixed.close()
    longer.close()


def test_oversized_subscription_frames_cost_nothing(tmp_path, daemon_factory):
    """One 8 MB subscription cost ~880 MB and tripped an overrun; 200 MB ones drove RSS to
    14 GB and SIGTERM was ignored. Now the connection is dropped at the frame's header."""
    from support.zmtp import RawPeer

    d = daemon_factory(sim_config(tmp_path, clock="realtime"))
    d.wait_welcome()
    [outlet] = _outlets(d)
    before = {pid: _status_kb(pid, "VmRSS") for pid in (d.proc.pid, outlet)}
    for size in (8_000_000, 200_000_000, 8_000_000):
        peer = RawPeer(d.pub)
        written = peer.send_oversized(size)
        peer.close()
        assert written < 8_000_000, written  # what the kernel buffered before the hang-up
    _, beat = d.next_message("heartbeat", timeout_s=10)  # still publishing to the others
    assert _outlets(d) == [outlet]  # and the same outlet: nothing came near its memory cap
    for pid, rss_kb in before.items():
        assert _status_kb(pid, "VmHWM") - rss_kb < 50 * 1024
    status = d.request({"cmd": "status"})
    assert status["fault"] is None and status["missed"] == 0
    d.proc.send_signal(signal.SIGTERM)
    assert d.proc.wait(30) == 0


def test_a_flood_of_subscriptions_costs_the_daemon_nothing_and_subscribers_come_back(tmp_path, daemon_factory):
    """Distinct subscription prefixes cost libzmq ~50 bytes per byte and keep the call
    that reads them busy for as long as they stream: inside the daemon that froze the
    sample loop (this test hung). The outlet process takes them: it drops every subscriber
    connection past its budget and ends at its memory cap; the daemon restarts it."""
    from support.zmtp import RawPeer

    d = daemon_factory(sim_config(tmp_path, clock="realtime"))
    d.wait_welcome()
    watcher = _subscriber(d, b"heartbeat")
    rss_before = _status_kb(d.proc.pid, "VmRSS")
    sent = 0
    while sent < 30_000:  # about 7 MB of subscriptions; the flooder reconnects whenever it is dropped
        try:
            peer = RawPeer(d.pub)
        except OSError:
            continue
        try:
            while sent < 30_000:
                peer.send(b"\x01" + os.urandom(250))
                sent += 1
        except OSError:
            pass  # dropped by the outlet: the next connection goes on
        finally:
            peer.close()
    status = d.request({"cmd": "status"})
    assert status["fault"] is None and status["missed"] == 0  # the sample loop never stalled
    assert _status_kb(d.proc.pid, "VmHWM") - rss_before < 50 * 1024
    # the watcher was dropped with everyone and came back by itself, welcome included
    while True:
        assert watcher.poll(30_000), "the watcher was never welcomed again"
        if welcome_instance(watcher.recv_multipart()) is not None:
            break
    assert _topics_until_heartbeats(watcher) == {"heartbeat"}
    watcher.close()
    d.proc.send_signal(signal.SIGTERM)
    assert d.proc.wait(30) == 0
    log = d.proc.stderr.read().decode()
    assert "dropping every subscriber connection" in log and "Traceback" not in log


def test_an_outlet_that_dies_is_replaced_and_the_daemon_does_not_notice(tmp_path, daemon_factory):
    d = daemon_factory(sim_config(tmp_path, clock="realtime"))
    d.wait_welcome()
    [outlet] = _outlets(d)
    os.kill(outlet, signal.SIGKILL)
    d.wait_welcome()  # our subscription is attached to the new outlet
    [new] = _outlets(d)
    assert new != outlet
    _, beat = d.next_message("heartbeat", timeout_s=10)
    status = d.request({"cmd": "status"})
    assert status["fault"] is None and status["missed"] == 0
    d.proc.send_signal(signal.SIGTERM)
    assert d.proc.wait(30) == 0
    assert b"publisher outlet ended (exit code -9)" in d.proc.stderr.read()
    assert not os.path.exists(f"/proc/{new}")  # stopped with the daemon


def test_a_killed_daemon_leaves_no_outlet_behind(tmp_path, daemon_factory):
    import select

    d = daemon_factory(sim_config(tmp_path, clock="realtime"))
    d.wait_welcome()
    [outlet] = _outlets(d)
    exited = os.pidfd_open(outlet)  # readable once the outlet has exited
    try:
        d.proc.kill()
        assert select.select([exited], [], [], 30)[0], "the outlet outlived its daemon"
    finally:
        os.close(exited)
