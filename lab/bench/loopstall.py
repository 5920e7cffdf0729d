"""``python -m lab bench loopstall``: how far the daemon's loop falls behind its samples
during each of a fresh daemon's first measures, beside busy processes.

Starts ``fluidsense simcell`` and, ``--runs`` times, a fresh ``fluidsense run`` (the
shipped gripper config, ``config/cell-gripper-modbus-sim.yaml``, calibrated, with the
default ``supervision.overrun_s`` of 0.25 s instead of its 2 s; real-time priority as
the daemon asks for it; recording as shipped, ``--no-record`` without), starts ``--load``
busy processes (``while True: pass``), and takes ``--measures`` measures (the first
stores the free-air reference). For each measure it reports the loop's lag: how old the
newest sample of each pressure batch is when the daemon sends it (``sent_s``), its
largest value over the measure, and the faults during it or just before it (``overrun``
is the lag ``overrun_s`` beyond its best). A fresh daemon's first grasp is where anything
it had not imported yet is imported, in the loop.
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

NAME = "loopstall"
HELP = "the daemon's loop lag during a fresh daemon's first measures, beside busy processes (overrun)"
DESCRIPTION = __doc__


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runs", type=int, default=5, help="fresh daemons (default 5)")
    p.add_argument("--measures", type=int, default=3, help="measures per daemon, the first the reference (default 3)")
    p.add_argument("--load", type=int, default=2, help="busy processes during the measures (default 2)")
    p.add_argument("--no-record", dest="record", action="store_false",
                   help="without the daemon's recording (its writer thread), which is on as shipped")
    p.add_argument("--json", action="store_true")


def _cell(tmp: Path, host: str, record: bool = True) -> Path:
    from lab import REPO

    path = REPO / "config" / "cell-gripper-modbus-sim.yaml"
    cell = yaml.safe_load(path.read_text())
    cell["driver"]["host"] = host
    cell["profile"] = str((path.parent / cell["profile"]).resolve())
    cell["gripper"]["calibrations"] = [str((path.parent / c).resolve()) for c in cell["gripper"]["calibrations"]]
    cell["supervision"] = {"no_data_s": 5.0}  # overrun_s: the default 0.25 s
    cell["publisher"] = {"pub": f"ipc://{tmp}/pub", "cmd": f"ipc://{tmp}/cmd"}
    cell["recording"] = {"enabled": record, "dir": str(tmp / "runs"), "min_free_mb": 16}
    cell["log_level"] = "WARNING"
    out = tmp / "cell.yaml"
    out.write_text(yaml.safe_dump(cell))
    return out


def _request(ctx: zmq.Context, tmp: Path, body: dict[str, Any]) -> dict[str, Any]:
    req = ctx.socket(zmq.REQ)
    req.setsockopt(zmq.LINGER, 0)
    req.connect(f"ipc://{tmp}/cmd")
    try:
        req.send(json.dumps(body).encode())
        if not req.poll(30_000):
            raise RuntimeError(f"no reply to {body}")
        return json.loads(req.recv())
    finally:
        req.close()


def _one_daemon(tmp: Path, cfg: Path, measures: int, load: int) -> list[dict[str, Any]]:
    ctx = zmq.Context()
    sub = ctx.socket(zmq.SUB)
    for topic in (b"pressure", b"cycle", b"fault"):
        sub.setsockopt(zmq.SUBSCRIBE, topic)
    sub.connect(f"ipc://{tmp}/pub")
    daemon = subprocess.Popen([sys.executable, "-m", "fluidsense", "run", "--config", str(cfg)],
                              stderr=subprocess.DEVNULL)
    burners: list[subprocess.Popen] = []
    out = []
    try:
        deadline = time.monotonic() + 120
        while _request(ctx, tmp, {"cmd": "status"}).get("state") in (None, "connecting"):
            if time.monotonic() > deadline:
                raise RuntimeError("the daemon did not connect within 120 s")
            sub.poll(500)
        burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(load)]
        for k in range(measures):
            between = []  # a fault latched between measures (its event is read with the next measure's)
            while True:
                status = _request(ctx, tmp, {"cmd": "status"})
                if status.get("fault") is not None:
                    between.append(status["fault"]["kind"])
                    _request(ctx, tmp, {"cmd": "reset"})
                elif status.get("state") == "idle":
                    break
                sub.poll(200)
            started = _request(ctx, tmp, {"cmd": "measure", "store_reference": k == 0})
            if not started.get("ok"):
                raise RuntimeError(f"measure refused: {started}")
            lags, faults = [], []
            while True:
                if not sub.poll(120_000):
                    raise RuntimeError("no cycle event within 120 s")
                topic, raw = sub.recv_multipart()
                msg = json.loads(raw)
                if topic == b"pressure":
                    lags.append(msg["sent_s"] - (msg["clock_origin_s"] + msg["times_s"][-1]))
                elif topic == b"fault":
                    faults.append({"kind": msg["kind"], "detail": msg["detail"]})
                    _request(ctx, tmp, {"cmd": "reset"})
                elif msg["cycle_id"] == started["cycle_id"]:
                    break
            out.append({"measure": k + 1, "lag_max_s": float(max(lags)), "lag_p50_s": float(np.median(lags)),
                        "faults": faults, "faults_before": between})
    finally:
        for b in burners:
            b.kill()
            b.wait()
        daemon.terminate()
        try:
            daemon.wait(30)
        except subprocess.TimeoutExpired:
            daemon.kill()
        sub.close()
        ctx.term()
    return out


def run_bench(runs: int, measures: int, load: int, record: bool = True) -> dict[str, Any]:
    from fluidsense.simulator.controlbox.process import EmulatorProcess, free_loopback

    res: dict[str, Any] = {"runs": runs, "measures": measures, "load": load, "record": record, "daemons": [],
                           "loadavg_at_start": Path("/proc/loadavg").read_text().split()[:3]}
    with tempfile.TemporaryDirectory(prefix="fluidsense-bench-loopstall-") as d:
        tmp = Path(d)
        cfg = _cell(tmp, free_loopback(), record)
        box = EmulatorProcess(command=[sys.executable, "-m", "fluidsense", "simcell", "--config", str(cfg)])
        box.start(timeout_s=60)
        try:
            for _ in range(runs):
                res["daemons"].append(_one_daemon(tmp, cfg, measures, load))
        finally:
            box.stop()
            box.__exit__(None, None, None)
    res["by_measure"] = [{"measure": k + 1,
                          "lag_max_s": sorted(round(dm[k]["lag_max_s"], 4) for dm in res["daemons"]),
                          "overruns": sum(f["kind"] == "overrun" for dm in res["daemons"] for f in dm[k]["faults"])}
                         for k in range(measures)]
    return res


def run(args: argparse.Namespace) -> int:
    res = run_bench(args.runs, args.measures, args.load, args.record)
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    print(f"{args.runs} fresh daemons ({'recording' if args.record else 'not recording'}), {args.measures} measures "
          f"each, beside {args.load} busy processes (load average {' '.join(res['loadavg_at_start'])}):")
    for m in res["by_measure"]:
        lags = ", ".join(f"{x * 1e3:.0f}" for x in m["lag_max_s"])
        print(f"  measure {m['measure']}: largest loop lag per daemon {lags} ms; overrun faults {m['overruns']}")
    return 0
