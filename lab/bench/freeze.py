"""``python -m lab bench freeze``: a box whose inputs stand still for less than
``stuck_s`` inside a measuring window (docs/safety.md, "A freeze shorter than stuck_s").

Starts ``fluidsense simcell`` (the emulated UR box, Modbus, 500 Hz) and ``fluidsense run``
with the sorting gripper's quick profile (window 0.5-0.55 s after the valve opens), takes
a free-air reference, then alternates ``--measures`` plain measures with as many whose
box freezes its inputs for ``--freeze-cycles`` I/O cycles from ``--delay-s`` after the
actuation output turns on (sim control ``lie``, ``freeze``). Prints, for each kind, the
longest run of unchanged p_act readings in the measured span (``unchanged_s``: what a
live box's own repeats come to), how many the daemon marked ``unreliable``, and P_eq
against the plain measures' mean (what the freeze does to the reading).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml
import zmq

NAME = "freeze"
HELP = "a box whose inputs freeze for less than stuck_s in the window: unchanged runs, unreliable marks, P_eq error"
DESCRIPTION = __doc__


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("--measures", type=int, default=10, help="plain measures, and as many frozen ones (default 10)")
    p.add_argument("--freeze-cycles", type=int, default=100, help="I/O cycles the box freezes (default 100: 0.2 s)")
    p.add_argument("--delay-s", type=float, default=0.45, help="from the actuation output on (default 0.45)")
    p.add_argument("--json", action="store_true")


def _cell(tmp: Path, host: str) -> Path:
    from lab import REPO

    cell = yaml.safe_load((REPO / "config" / "cell-modbus-sim.yaml").read_text())
    cell["driver"].update(host=host, arm=None)
    cell["profile"] = str(REPO / "config" / "profiles" / "sorting-gripper-quick.yaml")
    cell["publisher"] = {"pub": f"ipc://{tmp}/pub", "cmd": f"ipc://{tmp}/cmd"}
    cell["recording"] = {"enabled": False}
    cell["gripper"] = {}
    cell["log_level"] = "WARNING"
    path = tmp / "cell.yaml"
    path.write_text(yaml.safe_dump(cell))
    return path


class _Daemon:
    def __init__(self, tmp: Path, cfg: Path):
        self.tmp = tmp
        self.proc = subprocess.Popen([sys.executable, "-m", "fluidsense", "run", "--config", str(cfg)],
                                     stderr=subprocess.PIPE)
        self.ctx = zmq.Context()
        self.sub = self.ctx.socket(zmq.SUB)
        for topic in (b"cycle", b"fault"):
            self.sub.setsockopt(zmq.SUBSCRIBE, topic)
        self.sub.connect(f"ipc://{tmp}/pub")

    def request(self, body: dict[str, Any]) -> dict[str, Any]:
        req = self.ctx.socket(zmq.REQ)
        req.setsockopt(zmq.LINGER, 0)
        req.connect(f"ipc://{self.tmp}/cmd")
        try:
            req.send(json.dumps(body).encode())
            if not req.poll(30_000):
                raise RuntimeError(f"no reply to {body}")
            return json.loads(req.recv())
        finally:
            req.close()

    def measure(self, **body: Any) -> dict[str, Any]:
        """One measure (waiting until the cell is idle and connected); its cycle event."""
        while True:
            status = self.request({"cmd": "status"})
            if status.get("state") == "idle" and status.get("fault") is None:
                break
            if status.get("fault") is not None:
                raise RuntimeError(f"the daemon faulted: {status['fault']}")
            self.sub.poll(200)
        started = self.request({"cmd": "measure", **body})
        if not started.get("ok"):
            raise RuntimeError(f"measure refused: {started}")
        while True:
            if not self.sub.poll(120_000):
                raise RuntimeError("no cycle event within 120 s")
            topic, raw = self.sub.recv_multipart()
            msg = json.loads(raw)
            if topic == b"fault":
                raise RuntimeError(f"fault {msg['kind']}: {msg['detail']}")
            if msg["cycle_id"] == started["cycle_id"]:
                return msg

    def close(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        self.sub.close()
        self.ctx.term()


def run_bench(measures: int, freeze_cycles: int, delay_s: float) -> dict[str, Any]:
    from fluidsense.simulator.controlbox.process import EmulatorProcess, free_loopback

    out: dict[str, Any] = {"measures": measures, "freeze_cycles": freeze_cycles, "delay_s": delay_s,
                           "plain": [], "frozen": []}
    with tempfile.TemporaryDirectory(prefix="fluidsense-bench-freeze-") as d:
        tmp = Path(d)
        cfg = _cell(tmp, free_loopback())
        box = EmulatorProcess(command=[sys.executable, "-m", "fluidsense", "simcell", "--config", str(cfg)])
        box.start(timeout_s=60)
        daemon = None
        try:
            daemon = _Daemon(tmp, cfg)
            deadline = time.monotonic() + 120
            while daemon.request({"cmd": "status"}).get("state") in (None, "connecting"):
                if time.monotonic() > deadline:
                    raise RuntimeError("the daemon did not connect within 120 s")
                daemon.sub.poll(500)
            daemon.measure(store_reference=True)
            for _ in range(measures):
                out["plain"].append(_keep(daemon.measure()))
                told = box.command({"cmd": "lie", "kind": "freeze", "count": freeze_cycles, "on_output": 1,
                                    "delay_s": delay_s})
                if not told.get("ok"):
                    raise RuntimeError(f"the box refused the lie: {told}")
                out["frozen"].append(_keep(daemon.measure()))
        finally:
            if daemon is not None:
                daemon.close()
            box.stop()
            box.__exit__(None, None, None)
    plain_mean = float(np.mean([c["p_eq_kpa"] for c in out["plain"]]))
    for kind in ("plain", "frozen"):
        rows = out[kind]
        unchanged = np.array([c["unchanged_s"] for c in rows]) * 1e3
        error = np.array([c["p_eq_kpa"] for c in rows]) - plain_mean
        out[f"{kind}_summary"] = {
            "unchanged_ms": {"min": float(unchanged.min()), "median": float(np.median(unchanged)),
                             "max": float(unchanged.max())},
            "unreliable": sum(c["unreliable"] is not None for c in rows),
            "p_eq_minus_plain_mean_kpa": {"min": float(error.min()), "median": float(np.median(error)),
                                          "max": float(error.max())}}
    return out


def _keep(cycle: dict[str, Any]) -> dict[str, Any]:
    return {k: cycle[k] for k in ("cycle_id", "p_eq_kpa", "unchanged_s", "unreliable", "missed")}


def run(args: argparse.Namespace) -> int:
    res = run_bench(args.measures, args.freeze_cycles, args.delay_s)
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    print(f"{args.measures} plain and {args.measures} frozen measures ({args.freeze_cycles} I/O cycles from "
          f"{args.delay_s:g} s after the valve opens), sorting-gripper-quick over Modbus at 500 Hz:")
    for kind in ("plain", "frozen"):
        s = res[f"{kind}_summary"]
        u, e = s["unchanged_ms"], s["p_eq_minus_plain_mean_kpa"]
        print(f"  {kind:6}: longest unchanged p_act run min/median/max {u['min']:.1f}/{u['median']:.1f}/"
              f"{u['max']:.1f} ms; unreliable {s['unreliable']} of {args.measures}; P_eq - plain mean "
              f"min/median/max {e['min']:+.4f}/{e['median']:+.4f}/{e['max']:+.4f} kPa")
    return 0
