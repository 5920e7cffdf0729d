"""``python -m lab bench suite-cpu``: where a test run's CPU goes, per test file and per kind
of process the tests start.

The suite is CPU-bound on two cores: its wall time is its CPU over what the workers keep
busy, so a shorter ``make test`` needs less CPU, and this says where it is. Each test's CPU
is read around it (``getrusage`` of the worker, and of the children it reaped during the
test); each Python process the run starts (daemons, emulated boxes, samplers, CLI
commands) reports its own CPU as it ends, through a ``sitecustomize`` on its PYTHONPATH
(both probes: ``_suitecpu_probe/``; this module runs the pytest run and sums up).
A process killed by SIGKILL, or started with an environment of its own (without the
run's PYTHONPATH), reports nothing: its CPU is in the tests' child total only (the line
"not reported").
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

NAME = "suite-cpu"
HELP = "CPU of a test run, per test file and per kind of process the tests start"
DESCRIPTION = ("Run pytest with PYTEST_ARGS (make suite-cpu: make test's) and print the CPU "
               "of each test file (in the worker, and in the processes its tests started) and of each kind of "
               "process started: what a shorter suite must take away.")

# what runs inside the measured processes: a sitecustomize and a pytest plugin
PROBE = Path(__file__).with_name("_suitecpu_probe")


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("--top", type=int, default=25, help="rows of each table (default 25)")
    p.add_argument("--json", action="store_true")
    p.add_argument("pytest_args", nargs=argparse.REMAINDER, metavar="-- PYTEST_ARGS",
                   help="what pytest runs, after --, with its options (make suite-cpu gives make test's: the "
                   "unit and system tiers, its workers and their scheduling)")


def process_kind(argv: list[str]) -> str:
    """A short name for a process's command line: ``fluidsense run``, ``-m
    fluidsense.drivers.sampler.process``, ``-c`` and the start of a script given inline."""
    args = argv[1:]
    while args and args[0] in ("-u", "-B", "-E", "-s", "-I"):
        args = args[1:]
    if not args:
        return "python"
    if args[0] == "-m" and len(args) > 1:
        if args[1] in ("fluidsense", "lab") and len(args) > 2:
            return f"{args[1]} {args[2]}"
        return f"-m {args[1]}"
    if args[0] == "-c":
        return "-c " + " ".join((args[1] if len(args) > 1 else "").split())[:40]
    return Path(args[0]).name


def summarise(folder: Path, top: int) -> dict:
    tests = [json.loads(line) for f in sorted(folder.glob("tests.*.jsonl")) for line in f.read_text().splitlines()]
    procs = [json.loads(line) for line in (folder / "procs.jsonl").read_text().splitlines()] \
        if (folder / "procs.jsonl").exists() else []
    files: dict[str, dict[str, float]] = defaultdict(lambda: {"tests": 0, "wall_s": 0.0, "self_s": 0.0, "child_s": 0.0})
    for t in tests:
        row = files[t["id"].split("::")[0]]
        row["tests"] += 1
        for key in ("wall_s", "self_s", "child_s"):
            row[key] += t[key]
    own = {int(x) for x in (folder / "pytest-pids").read_text().split()} if (folder / "pytest-pids").exists() else set()
    kinds: dict[str, dict[str, float]] = defaultdict(lambda: {"n": 0, "cpu_s": 0.0})
    for p in procs:
        if p["pid"] in own:
            continue
        row = kinds[process_kind(p["argv"])]
        row["n"] += 1
        row["cpu_s"] += p["cpu_s"]
    self_s = sum(t["self_s"] for t in tests)
    child_s = sum(t["child_s"] for t in tests)
    started = sum(v["cpu_s"] for v in kinds.values())
    by_cpu = sorted(files.items(), key=lambda kv: -(kv[1]["self_s"] + kv[1]["child_s"]))
    return {"tests": len(tests), "self_s": self_s, "child_s": child_s,
            "started_reported_s": started, "not_reported_s": max(child_s - started, 0.0),
            "files": [{"file": k, **v} for k, v in by_cpu[:top]],
            "slowest": sorted(tests, key=lambda t: -(t["self_s"] + t["child_s"]))[:top],
            "kinds": [{"kind": k, **v} for k, v in sorted(kinds.items(), key=lambda kv: -kv[1]["cpu_s"])][:top]}


def run(args: argparse.Namespace) -> int:
    with tempfile.TemporaryDirectory(prefix="fluidsense-suitecpu-") as tmp:
        folder = Path(tmp)
        env = {**os.environ, "FLUIDSENSE_SUITECPU_DIR": tmp,
               "PYTHONPATH": os.pathsep.join(filter(None, [str(PROBE), os.environ.get("PYTHONPATH")]))}
        pytest_args = args.pytest_args[1:] if args.pytest_args[:1] == ["--"] else args.pytest_args
        cmd = [sys.executable, "-m", "pytest", *pytest_args, "-q", "-p", "fluidsense_suitecpu_plugin",
               "-p", "no:cacheprovider"]
        before = os.times()
        t0 = time.monotonic()
        # the run's own output goes to stderr: stdout is this bench's figures
        rc = subprocess.run(cmd, env=env, stdout=sys.stderr).returncode
        wall = time.monotonic() - t0
        after = os.times()
        out = summarise(folder, args.top)
    out.update({"command": " ".join(cmd[1:]), "exit_code": rc, "wall_s": wall,
                "cpu_s": (after.children_user - before.children_user) + (after.children_system - before.children_system)})
    if args.json:
        print(json.dumps(out, indent=2))
        return rc
    print(f"{out['command']}: exit {rc}, {out['tests']} tests, {wall:.0f} s wall, {out['cpu_s']:.0f} s CPU "
          f"({out['cpu_s'] / wall:.2f} cores)")
    print(f"in the workers {out['self_s']:.0f} s; in the processes the tests started {out['child_s']:.0f} s "
          f"(reported as they ended {out['started_reported_s']:.0f} s; not reported, killed or started with "
          f"an environment of their own: {out['not_reported_s']:.0f} s)")
    print("\nper test file (CPU s: in the worker + in its processes, wall s, tests):")
    for f in out["files"]:
        print(f"  {f['self_s'] + f['child_s']:7.1f} = {f['self_s']:6.1f} + {f['child_s']:6.1f}  "
              f"{f['wall_s']:7.1f}  {f['tests']:4d}  {f['file']}")
    print("\nper kind of process started (CPU s, processes, mean):")
    for k in out["kinds"]:
        print(f"  {k['cpu_s']:7.1f}  {k['n']:4d}  {k['cpu_s'] / k['n']:6.2f}  {k['kind']}")
    print("\nthe costliest tests (CPU s = worker + processes, wall s):")
    for t in out["slowest"]:
        print(f"  {t['self_s'] + t['child_s']:7.1f} = {t['self_s']:6.1f} + {t['child_s']:6.1f}  {t['wall_s']:7.1f}  {t['id']}")
    return rc
