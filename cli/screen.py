"""``fluidsense monitor`` for a person: one screen, redrawn in place.

What the screen shows comes from two places: the PUB socket (pressure, state, cycles,
faults, heartbeats) and, once a second, ``status`` on the command socket (the valve
outputs as the device reports them, the fault in full, whether the vent was confirmed).
``View`` keeps what was heard and ``render`` turns it into lines; both are plain
functions of the messages, so that tests read the screen without a terminal.

Nothing stale is shown as current: every message and status reply names the daemon
instance it comes from, and one from another instance (a daemon restarted on the same
endpoints) starts the view afresh, so that its sample time, cycle and counts are never
mixed with the old one's. A daemon that says it stopped (its last message), or stops
answering ``status``, is shown as such: no state, its last results marked as its last.
"""

from __future__ import annotations

import json
import sys
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, TextIO

import zmq
from fluidsense.cli.contact import t_c_text
from fluidsense.common.names import welcome_instance

TRACE_S = 10.0  # seconds of pressure in the trace
TRACE_COLS = 60
SPARK = "▁▂▃▄▅▆▇█"
RESULTS = 5
REDRAW_S = 0.25
STATUS_S = 1.0
STATUS_TIMEOUT_S = 0.5

# what a fault means and what to do next (docs/bringup.md, "What each fault means")
FAULT_ADVICE = {
    "over_pressure": "pressure above the profile's limit: check the regulator and the tank valve, then reset",
    "under_pressure": "pressure below the limit: look for a leak or a torn actuator",
    "sensor_nan": "the sensor gave no number: check its cable and the analog input",
    "sensor_range": "the sensor reads out of range: dead, saturated or miswired (fluidsense check)",
    "sensor_stuck": "the reading stopped changing: the sensor or its input is frozen",
    "leak": "pressure falls while the valves are closed: check the tubing and the actuator",
    "protective_stop": "the robot stopped itself: clear it on the teach pendant",
    "no_data": "no samples arrive: the device or its link stalled",
    "link_lost": "the connection to the control box is gone: check the cable and the box",
    "overrun": "the sample loop fell behind: the PC is overloaded",
    "driver": "the device driver failed: see the daemon's log",
    "command": "a valve or setpoint was not carried out: check the wiring (fluidsense check)",
    "internal": "a bug inside the daemon (vented): see its log and report it",
}


@dataclass
class View:
    """What the monitor has heard so far."""

    state: str = "?"
    cycle_id: int | None = None
    t_s: float = 0.0
    heartbeat: dict[str, Any] = field(default_factory=dict)
    status: dict[str, Any] | None = None
    status_error: str | None = None
    results: deque = field(default_factory=lambda: deque(maxlen=RESULTS))
    faults: deque = field(default_factory=lambda: deque(maxlen=3))
    task: dict[str, Any] | None = None
    channels: list[str] = field(default_factory=list)
    units: list[str] = field(default_factory=list)
    trace: deque = field(default_factory=deque)  # (t_s, [values]) in the units of the message
    missed_messages: int = 0
    last_seq: int | None = None
    heard: bool = False
    instance: str = ""  # the daemon instance all of this is from ("": one that sends no id)
    gone: str | None = None  # why the daemon is taken to be gone (stopped, not answering), else None

    def _same_daemon(self, instance: str | None) -> None:
        """A message or reply from another daemon instance: forget the old one's."""
        if instance and instance != self.instance:
            if self.instance:
                self.__init__()  # a fresh view: nothing of the old daemon is kept or mixed in
            self.instance = instance

    def take_welcome(self, instance: str) -> None:
        self._same_daemon(instance)

    def take(self, topic: str, msg: dict[str, Any]) -> None:
        self._same_daemon(msg.get("instance"))
        self.heard = True
        seq = msg.get("seq")
        if self.last_seq is not None and seq is not None and seq > self.last_seq + 1:
            self.missed_messages += seq - self.last_seq - 1
        self.last_seq = seq if seq is not None else self.last_seq
        self.t_s = max(self.t_s, float(msg.get("t_s") or 0.0))
        if topic == "log" and msg.get("message") == "controller stopped":  # the daemon's last message
            self.lost("stopped")
            return
        self.gone = None
        if topic == "pressure":
            self.channels, self.units = msg["channels"], msg.get("units", ["kPa"] * len(msg["channels"]))
            for i, t in enumerate(msg["times_s"]):
                self.trace.append((t, [row[i] for row in msg["values"]]))
            while self.trace and self.trace[-1][0] - self.trace[0][0] > TRACE_S:
                self.trace.popleft()
        elif topic == "state":
            self.state, self.cycle_id = msg["to"], msg.get("cycle_id")
        elif topic == "heartbeat":
            self.heartbeat = msg
            self.state, self.cycle_id = msg.get("state", self.state), msg.get("cycle_id", self.cycle_id)
        elif topic == "cycle":
            self.results.append(msg)
        elif topic == "fault":
            self.faults.append(msg)
        elif topic == "task":
            self.task = msg


    def take_status(self, status: dict[str, Any]) -> None:
        """A ``status`` reply: an idle daemon in virtual time publishes nothing, status still says where it is."""
        self._same_daemon(status.get("instance"))
        self.heard, self.status, self.status_error, self.gone = True, status, None, None
        self.state, self.cycle_id = status.get("state", self.state), status.get("cycle_id", self.cycle_id)
        self.t_s = max(self.t_s, float(status.get("t_s") or 0.0))

    def lost(self, why: str) -> None:
        """The daemon stopped, or does not answer ``status`` (``why``): what it was doing is
        no longer known. Its results stay, marked as its last."""
        self.gone = self.gone or why  # the first word stays: "stopped", then no replies
        self.state, self.cycle_id, self.status = "?", None, None
        self.heartbeat, self.trace, self.channels, self.units = {}, deque(), [], []
        if why != "stopped":
            self.status_error = why


def sparkline(values: list[float], cols: int = TRACE_COLS) -> str:
    """``values`` squeezed into ``cols`` characters, scaled between their min and max."""
    if not values:
        return ""
    step = max(1, len(values) // cols)
    pts = [values[i] for i in range(0, len(values), step)][-cols:]
    lo, hi = min(pts), max(pts)
    span = hi - lo or 1.0
    return "".join(SPARK[round((v - lo) / span * (len(SPARK) - 1))] for v in pts)


def result_line(msg: dict[str, Any]) -> str:
    if not msg.get("ok"):
        return f"cycle {msg['cycle_id']}: FAILED ({msg.get('aborted')})"
    parts = [f"P_eq {msg['p_eq_kpa']:.3f} ± {1.96 * (msg.get('p_sd_kpa') or 0.0):.3f} kPa (95 %)"]
    if msg.get("dp_eq_kpa") is not None:
        parts.append(f"dP {msg['dp_eq_kpa']:.3f} kPa")
    if (t_c := t_c_text(msg)) is not None:
        parts.append(t_c)
    tag = " reference" if msg.get("is_reference") else (f" {msg['label']}" if msg.get("label") else "")
    return f"cycle {msg['cycle_id']}{tag}: " + ", ".join(parts)


def _valves(status: dict[str, Any]) -> str:
    reported = status.get("valves")
    if not reported:
        return "valves: not reported by the device"
    words = ", ".join(f"{name} {'open' if on else 'closed'}" for name, on in sorted(reported.items()))
    age = status.get("valves_age_s")
    return f"valves (device): {words}" + (f"  [{age:.1f} s ago]" if isinstance(age, (int, float)) else "")


def _scheduling(hb: dict[str, Any]) -> str:
    """The loop's real-time priority and the dead-link vent, where the heartbeat carries them:
    a refused priority or no vent path is what an operator must not miss."""
    out = ""
    rt = hb.get("realtime")
    if rt is not None and rt != "not_needed":
        out += f", real-time priority {'REFUSED' if rt == 'refused' else rt}"
    vent = hb.get("vent_path")
    if vent == "none":
        out += ", NO VENT on a dead link (fluidsense check)"
    return out


def render(view: View, sub_endpoint: str, cmd_endpoint: str | None) -> list[str]:
    """The screen as lines."""
    if not view.heard:
        return [f"fluidsense monitor: waiting for the daemon at {sub_endpoint}"
                + (f" and {cmd_endpoint}" if cmd_endpoint else ""),
                "nothing heard yet: is it running (fluidsense run), and is this its publisher endpoint "
                "(--endpoint, or publisher.pub in --config)?"]
    hb = view.heartbeat
    daemon = f"   daemon {view.instance}" if view.instance else ""
    if view.gone is not None:
        who = f"the daemon {view.instance}" if view.instance else "the daemon"
        lines = [f"fluidsense  {who}: {view.gone}; its state is not known (last heard at t {view.t_s:.3f} s)"]
    else:
        lines = [f"fluidsense  t {view.t_s:9.3f} s   state {view.state.upper()}   cycle {view.cycle_id}"
                 + ("   (virtual time)" if hb.get("virtual") else "") + daemon]
    if hb:
        lines.append(f"loop: {hb.get('samples', 0)} samples, {hb.get('missed', 0)} missed, {hb.get('late', 0)} late"
                     f", block p99 {hb.get('block_proc_us', {}).get('p99', 0):.0f} us"
                     + (f", {view.missed_messages} messages lost" if view.missed_messages else "")
                     + _scheduling(hb))
    lines.append("")
    for j, ch in enumerate(view.channels):
        vals = [row[j] for _, row in view.trace if row[j] is not None]
        now = f"{vals[-1]:8.2f}" if vals else "     n/a"
        rng = f"[{min(vals):.1f} .. {max(vals):.1f}]" if vals else ""
        unit = view.units[j] if j < len(view.units) else ""
        lines.append(f"{ch:>8} {now} {unit:<4} {sparkline(vals)} {rng}")
    if not view.channels:
        lines.append("pressure: no samples yet")
    st = view.status
    if st is not None:
        lines.append(_valves(st) + f"   vented: {st.get('vented')}")
    elif cmd_endpoint is not None:
        lines.append(f"valves: no status from {cmd_endpoint}" + (f" ({view.status_error})" if view.status_error else ""))
    lines += ["", "last results:" if view.gone is None else "last results (of the daemon that is gone):"]
    lines += [f"  {result_line(r)}" for r in reversed(view.results)] or ["  none yet"]
    if view.task is not None:
        lines.append("task: " + json.dumps({k: v for k, v in view.task.items()
                                            if k not in ("schema", "instance", "topic", "seq", "t_s")})[:200])
    fault = (st or {}).get("fault") or (view.faults[-1] if view.faults else None)
    if fault:
        kind = fault.get("kind", "?")
        lines += ["", f"FAULT {kind}: {fault.get('detail', '')}",
                  f"  what to do: {FAULT_ADVICE.get(kind, 'see docs/safety.md')}"]
    return lines


def draw(lines: list[str], out: TextIO) -> None:
    """Home the cursor, write each line over the old one, clear what is left below."""
    out.write("\x1b[H" + "".join(f"{line}\x1b[K\n" for line in lines) + "\x1b[J")
    out.flush()


def run_screen(sub_endpoint: str, cmd_endpoint: str | None, out: TextIO = sys.stdout,
               duration_s: float | None = None) -> int:
    """Redraw until Ctrl-C (or ``duration_s``). Returns 0."""
    from .monitor import send_command

    ctx = zmq.Context.instance()
    sock = ctx.socket(zmq.SUB)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.SUBSCRIBE, b"")
    sock.connect(sub_endpoint)
    view = View()
    end = None if duration_s is None else time.monotonic() + duration_s
    next_draw = next_status = 0.0
    out.write("\x1b[2J")
    try:
        while end is None or time.monotonic() < end:
            if sock.poll(int(REDRAW_S * 1000)):
                while True:
                    try:
                        frames = sock.recv_multipart(zmq.NOBLOCK)
                    except zmq.Again:
                        break
                    welcome = welcome_instance(frames)
                    if welcome is not None:
                        view.take_welcome(welcome)
                    elif len(frames) == 2:
                        view.take(frames[0].decode(), json.loads(frames[1]))
            now = time.monotonic()
            if cmd_endpoint is not None and now >= next_status:
                next_status = now + STATUS_S
                try:
                    view.take_status(send_command(cmd_endpoint, {"cmd": "status"}, STATUS_TIMEOUT_S))
                except TimeoutError:  # its message names the endpoint, which the screen says already
                    view.lost(f"not answering status within {STATUS_TIMEOUT_S:g} s")
            if now >= next_draw:
                next_draw = now + REDRAW_S
                draw(render(view, sub_endpoint, cmd_endpoint), out)
    except KeyboardInterrupt:
        pass
    finally:
        sock.close()
    return 0
