"""``fluidsense monitor --log``: one line per message, for scripts (the screen a person
reads is cli/screen.py); ``send_command``: one request on the command socket."""

from __future__ import annotations

import json
import sys
from typing import Any, TextIO

import zmq
from fluidsense.cli.contact import t_c_text
from fluidsense.common.exitcodes import EXIT_OK, EXIT_TIMEOUT
from fluidsense.common.names import WELCOME, welcome_instance

NOT_RUNNING = ("the daemon may not be running (fluidsense run), or it listens elsewhere "
               "(its {what} endpoint: --endpoint, or {option} in --config)")


def format_message(topic: str, msg: dict[str, Any]) -> str | None:
    t = msg.get("t_s", 0.0)
    if topic == "state":
        return f"[{t:10.3f}] cycle {msg['cycle_id']}: {msg['from']} -> {msg['to']} ({msg['reason']})"
    if topic == "cycle":
        if not msg.get("ok"):
            return f"[{t:10.3f}] cycle {msg['cycle_id']} FAILED: {msg.get('aborted')}"
        parts = [f"P_eq {msg['p_eq_kpa']:.3f} +- {msg['p_sd_kpa']:.3f} kPa"]
        if msg.get("dp_eq_kpa") is not None:
            parts.append(f"dP {msg['dp_eq_kpa']:.3f} kPa")
        if (t_c := t_c_text(msg)) is not None:
            parts.append(t_c)
        ref = " (reference)" if msg.get("is_reference") else ""
        return f"[{t:10.3f}] cycle {msg['cycle_id']}{ref}: " + ", ".join(parts)
    if topic == "heartbeat":
        p = msg.get("block_proc_us", {})
        return (f"[{t:10.3f}] heartbeat: {msg['state']}, {msg['samples']} samples, {msg['missed']} missed, "
                f"block p99 {p.get('p99', 0):.0f} us, fault {msg.get('fault')}, real-time priority "
                f"{msg.get('realtime')}, dead-link vent {msg.get('vent_path')}")
    if topic == "fault":
        vented = {True: "vented", False: "NOT VENTED", "unknown": "vent not confirmed"}.get(msg.get("vented"), "vent not confirmed")
        return f"[{t:10.3f}] FAULT {msg['kind']}: {msg['detail']} ({vented})"
    if topic == "pressure":
        ch = msg["channels"]
        last = [row[-1] for row in msg["values"]]
        return f"[{t:10.3f}] pressure " + ", ".join(f"{c} {v:.2f} kPa" for c, v in zip(ch, last))
    if topic in ("task", "log"):
        return f"[{t:10.3f}] {topic}: " + json.dumps({k: v for k, v in msg.items()
                                                     if k not in ("schema", "instance", "topic", "seq", "t_s")})
    return None


def monitor(endpoint: str, topics: list[str], count: int | None, timeout_s: float | None,
            as_json: bool, out: TextIO = sys.stdout) -> int:
    """Print messages until ``count`` were shown or nothing arrived for ``timeout_s``.

    Returns 0, or EXIT_TIMEOUT (3) when the timeout passed without any message: no reply
    from the daemon, as for every command (docs/cli.md).
    """
    ctx = zmq.Context.instance()
    sock = ctx.socket(zmq.SUB)
    sock.setsockopt(zmq.LINGER, 0)
    for topic in topics:
        sock.setsockopt(zmq.SUBSCRIBE, topic.encode())
    sock.setsockopt(zmq.SUBSCRIBE, WELCOME)
    sock.connect(endpoint)
    shown = 0
    last_seq: int | None = None
    welcomed: str | None = None
    try:
        while count is None or shown < count:
            if timeout_s is not None and not sock.poll(int(timeout_s * 1000)):
                if not shown:
                    print(f"fluidsense monitor: nothing heard from {endpoint} within {timeout_s:g} s: "
                          f"{NOT_RUNNING.format(what='publisher', option='publisher.pub')}", file=sys.stderr)
                return EXIT_OK if shown else EXIT_TIMEOUT
            frames = sock.recv_multipart()
            welcome = welcome_instance(frames)
            if welcome is not None:
                # the same id again: another subscriber came, or ours was made again; a new id
                # is another daemon on the same endpoint (a restart)
                if not as_json and welcome != welcomed:
                    print(f"(connected to {endpoint}" + (f", daemon {welcome})" if welcome else ")"),
                          file=sys.stderr, flush=True)
                welcomed = welcome
                continue
            if len(frames) != 2:
                continue
            topic, msg = frames[0].decode(), json.loads(frames[1])
            seq = msg.get("seq")
            if last_seq is not None and seq is not None and seq > last_seq + 1 and topics == [""]:
                print(f"(missed {seq - last_seq - 1} messages)", file=out)
            last_seq = seq
            line = json.dumps(msg) if as_json else format_message(topic, msg)
            if line is not None:
                print(line, file=out, flush=True)
                shown += 1
    except KeyboardInterrupt:
        pass
    finally:
        sock.close()
    return 0


def send_command(endpoint: str, request: dict[str, Any], timeout_s: float = 5.0,
                 curve: tuple[str, str] | None = None) -> dict[str, Any]:
    """One request on the command socket, through the client library's core: its reply,
    an error reply included; raises TimeoutError if no reply comes. ``curve``: (client
    secret key file, server public key file) for a CURVE socket."""
    from fluidsense.client import Gripper, NoReply, Refused

    with Gripper(endpoint, None, timeout_s=timeout_s, curve=curve, context=zmq.Context.instance()) as client:
        try:
            return client.request(request)
        except Refused as refused:
            return refused.reply
        except NoReply:
            raise TimeoutError(f"no reply from {endpoint} within {timeout_s:g} s: "
                               + NOT_RUNNING.format(what="command", option="publisher.cmd")) from None
