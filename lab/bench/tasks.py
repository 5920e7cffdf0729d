"""``python -m lab bench tasks``: the README's production paths on a busy robot PC.

Runs the README's sorting task (``fluidsense task run config/tasks/sorting.yaml --config
config/cell-{ur,modbus}-sim.yaml --json``, a fresh input order each run) against
``fluidsense simcell``, with ``--load`` busy processes beside it (a robot PC running a
motion stack and a GUI looks like this), and counts the runs that sorted correctly; a
failed run is reported with the fault its output names. With ``--idle-s S`` it also
runs an idle real-time daemon on the simulated cell for S seconds under the same load and
counts the faults it latched (there should be none: nothing happens). With
``--empty-grips N`` it also grips nothing N times through each driver with the gripper
profile (config/cell-gripper-modbus-sim.yaml's gripper; ur: the same wiring through the
ur-rtde driver), once as shipped and once with the rise alignment switched off
(``sequence.align_rise_kpa: null``), after one free-air reference, and counts the grips
that reported an object: the valve's command latency on a busy PC against the dP threshold.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from ._procs import end as end_process

NAME = "tasks"
HELP = "the README's sorting task through ur and modbus, and an idle daemon, beside busy processes"
DESCRIPTION = __doc__
SIZES = [40.0, 60.0, 80.0, 100.0]


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runs", type=int, default=10, help="sorting runs per driver (default 10)")
    p.add_argument("--drivers", default="ur,modbus", help="comma-separated (default ur,modbus)")
    p.add_argument("--load", type=int, default=2, help="busy processes beside the cell (default 2)")
    p.add_argument("--idle-s", type=float, default=0.0, help="then an idle real-time daemon for this long (default 0)")
    p.add_argument("--seed", type=int, default=1, help="seed of the input orders")
    p.add_argument("--empty-grips", type=int, default=0,
                   help="then this many grips of nothing per driver, with and without rise alignment (default 0)")
    p.add_argument("--json", action="store_true")


def _cell(tmp: Path, kind: str, host: str, **sections: Any) -> Path:
    """config/cell-{kind}-sim.yaml at ``host``, sockets in ``tmp``, no recording; ``sections``
    replace whole sections."""
    import yaml

    from lab import REPO

    config = REPO / "config"
    data = yaml.safe_load((config / f"cell-{kind}-sim.yaml").read_text())
    data["driver"]["host"] = host
    data["profile"] = str((config / data["profile"]).resolve())
    data["publisher"] = {"pub": f"ipc://{tmp}/pub-{kind}", "cmd": f"ipc://{tmp}/cmd-{kind}"}
    data["recording"] = {"enabled": False}
    data.update(sections)
    path = tmp / f"cell-{kind}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _fault_line(stderr: str) -> str | None:
    for line in reversed(stderr.splitlines()):
        if "FAULT" in line or "stopped by" in line:
            return line.strip()[-300:]
    return stderr.strip().splitlines()[-1][-300:] if stderr.strip() else None


def _sorting(kind: str, runs: int, rng) -> dict[str, Any]:
    from fluidsense.simulator.controlbox.process import EmulatorProcess, free_loopback

    from lab import REPO

    out = {"driver": kind, "runs": runs, "sorted": 0, "durations_s": [], "failures": []}
    with tempfile.TemporaryDirectory(prefix="fluidsense-bench-tasks-") as d:
        cell = _cell(Path(d), kind, free_loopback())
        box = EmulatorProcess(command=[sys.executable, "-m", "fluidsense", "simcell", "--config", str(cell)])
        box.start(timeout_s=60)
        try:
            for _ in range(runs):
                order = [float(x) for x in rng.permutation(SIZES)]
                t0 = time.monotonic()
                res = subprocess.run([sys.executable, "-m", "fluidsense", "task", "run",
                                      str(REPO / "config" / "tasks" / "sorting.yaml"), "--config", str(cell),
                                      "--order", ",".join(f"{x:g}" for x in order), "--json"],
                                     capture_output=True, text=True, timeout=1800, cwd=REPO)
                wall = time.monotonic() - t0
                try:
                    summary = json.loads(res.stdout)
                except json.JSONDecodeError:
                    summary = {}
                if res.returncode == 0 and summary.get("final_order_mm") == sorted(order, reverse=True):
                    out["sorted"] += 1
                    out["durations_s"].append(round(wall, 1))
                else:
                    out["failures"].append({"order": order, "rc": res.returncode, "fault": summary.get("fault"),
                                            "said": _fault_line(res.stderr)})
        finally:
            box.stop()
            box.__exit__(None, None, None)
    return out


def _idle(seconds: float) -> dict[str, Any]:
    """An idle real-time daemon on the simulated cell: every fault it publishes."""
    import yaml
    import zmq

    from lab import REPO

    with tempfile.TemporaryDirectory(prefix="fluidsense-bench-idle-") as d:
        tmp = Path(d)
        cfg = yaml.safe_load((REPO / "config" / "cell-sim.yaml").read_text())
        cfg["profile"] = str((REPO / "config" / cfg["profile"]).resolve())
        cfg["publisher"] = {"pub": f"ipc://{tmp}/pub", "cmd": f"ipc://{tmp}/cmd"}
        cfg["recording"] = {"dir": str(tmp / "runs"), "min_free_mb": 16}
        path = tmp / "cell.yaml"
        path.write_text(yaml.safe_dump(cfg))
        ctx = zmq.Context()
        sub = ctx.socket(zmq.SUB)
        for topic in (b"fault", b"heartbeat"):
            sub.setsockopt(zmq.SUBSCRIBE, topic)
        sub.connect(cfg["publisher"]["pub"])
        daemon = subprocess.Popen([sys.executable, "-m", "fluidsense", "run", "--config", str(path)],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=REPO)
        faults, beats, last = [], 0, None
        end = time.monotonic() + seconds
        try:
            while time.monotonic() < end:
                if sub.poll(500):
                    topic, body = sub.recv_multipart()
                    msg = json.loads(body)
                    if topic == b"fault":
                        faults.append({"kind": msg["kind"], "detail": msg["detail"], "t_s": msg["fault_t_s"]})
                    else:
                        beats += 1
                        last = msg
        finally:
            end_process(daemon, 60)
            sub.close()
            ctx.term()
    return {"seconds": seconds, "faults": faults, "heartbeats": beats,
            "missed_samples": None if last is None else last["missed"],
            "block_proc_us_p99_last": None if last is None else last["block_proc_us"]["p99"]}


def _gripper_cell(tmp: Path, kind: str, host: str, align: bool) -> Path:
    """The shipped gripper cell (modbus), or its wiring through the ur-rtde driver (ur), with
    or without the profile's rise alignment."""
    import yaml

    from lab import REPO

    config = REPO / "config"
    gripper = yaml.safe_load((config / "cell-gripper-modbus-sim.yaml").read_text())
    data = gripper if kind == "modbus" else yaml.safe_load((config / "cell-ur-sim.yaml").read_text())
    data["driver"].update(host=host, wiring=gripper["driver"]["wiring"])
    profile = yaml.safe_load((config / gripper["profile"]).read_text())
    if not align:
        profile["sequence"]["align_rise_kpa"] = None
    (tmp / "profile.yaml").write_text(yaml.safe_dump(profile))
    data.update(profile=str(tmp / "profile.yaml"),
                gripper={"calibrations": [str(config / c) for c in gripper["gripper"]["calibrations"]]},
                publisher={"pub": f"ipc://{tmp}/pub", "cmd": f"ipc://{tmp}/cmd"}, recording={"enabled": False})
    path = tmp / "cell.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _empty_grips(kind: str, grips: int, align: bool) -> dict[str, Any]:
    """A free-air reference, then ``grips`` grips of nothing: how many read as an object."""
    import numpy as np
    from fluidsense.client import Gripper
    from fluidsense.simulator.controlbox.process import EmulatorProcess, free_loopback

    from lab import REPO

    out: dict[str, Any] = {"driver": kind, "align": align, "grips": grips, "objects": 0, "dp_max_kpa": []}
    with tempfile.TemporaryDirectory(prefix="fluidsense-bench-grips-") as d:
        cell = _gripper_cell(Path(d), kind, free_loopback(), align)
        box = EmulatorProcess(command=[sys.executable, "-m", "fluidsense", "simcell", "--config", str(cell)])
        box.start(timeout_s=60)
        try:
            daemon = subprocess.Popen([sys.executable, "-m", "fluidsense", "run", "--config", str(cell)],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=REPO)
        except BaseException:
            box.stop()
            box.__exit__(None, None, None)
            raise
        try:
            with Gripper(f"ipc://{d}/cmd", f"ipc://{d}/pub", timeout_s=120) as g:
                while g.status()["state"] == "connecting":
                    time.sleep(0.5)  # a bench waiting for the daemon's connection, nothing measured
                g.measure(store_reference=True)
                g.scene({"kind": "none"})
                for _ in range(grips):
                    grasp = g.grip()
                    out["objects"] += bool(grasp.object)
                    out["dp_max_kpa"].append(grasp.features["dp_max_kpa"])
                    g.release()
        finally:
            try:
                end_process(daemon, 60)
            finally:  # the box ends even if the daemon would not
                box.stop()
            box.__exit__(None, None, None)
    dp = np.abs(np.array([v for v in out["dp_max_kpa"] if v is not None]))
    out["dp_max_kpa"] = {"p50": round(float(np.median(dp)), 3), "max": round(float(dp.max()), 3)} if len(dp) else None
    return out


def run_bench(runs: int, drivers: list[str], load: int, idle_s: float, seed: int,
              empty_grips: int = 0) -> dict[str, Any]:
    import numpy as np

    from .timing import _burn

    rng = np.random.default_rng(seed)
    burners = [multiprocessing.Process(target=_burn, args=(time.monotonic() + 1e6,), daemon=True) for _ in range(load)]
    for b in burners:
        b.start()
    t0 = time.monotonic()
    try:
        sorting = [_sorting(kind, runs, rng) for kind in drivers] if runs > 0 else []
        idle = _idle(idle_s) if idle_s > 0 else None
        grips = [_empty_grips(kind, empty_grips, align) for kind in drivers for align in (True, False)] \
            if empty_grips > 0 else []
    finally:
        for b in burners:
            b.terminate()
            b.join()
    return {"load_processes": load, "cpus": os.cpu_count(), "sorting": sorting, "idle": idle, "empty_grips": grips,
            "wall_s": round(time.monotonic() - t0, 1)}


def run(args: argparse.Namespace) -> int:
    res = run_bench(args.runs, [d for d in args.drivers.split(",") if d], args.load, args.idle_s, args.seed,
                    args.empty_grips)
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    print(f"{res['load_processes']} busy processes on {res['cpus']} CPUs")
    for s in res["sorting"]:
        durations = s["durations_s"]
        span = f", {min(durations):.0f}-{max(durations):.0f} s each" if durations else ""
        print(f"sorting through {s['driver']}: {s['sorted']}/{s['runs']} sorted correctly{span}")
        for f in s["failures"]:
            print(f"  failed (rc {f['rc']}) on order {f['order']}: {f['said']}")
    if res["idle"] is not None:
        i = res["idle"]
        print(f"idle daemon {i['seconds']:.0f} s: {len(i['faults'])} faults, {i['heartbeats']} heartbeats, "
              f"{i['missed_samples']} samples missed")
        for f in i["faults"][:5]:
            print(f"  {f['kind']} at t={f['t_s']:.1f} s: {f['detail']}")
    for e in res["empty_grips"]:
        dp = e["dp_max_kpa"] or {"p50": float("nan"), "max": float("nan")}
        print(f"empty grips through {e['driver']}, rise alignment {'on' if e['align'] else 'off'}: "
              f"{e['objects']}/{e['grips']} read as an object; |dP_max| median {dp['p50']:.3f} kPa, max {dp['max']:.3f} kPa")
    return 0
