"""``python -m lab bench sampler``: timing of the sampler process (docs/architecture.md, decision 3).

Runs the real sampler process with the synthetic poller, reads its blocks like the
daemon does and prints the slot counts, the lateness distribution, the CPU the
sampler used and which real-time settings were applied. ``--load N`` adds N processes
of competing CPU and memory load (normal priority, any CPU) for the whole run.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import platform
import subprocess
import sys
import time

import numpy as np

NAME = "sampler"
HELP = "lateness, missed slots and CPU of the sampler process (synthetic poller, real time)"
DESCRIPTION = ("Run the sampler process at --rate-hz for --seconds with the synthetic poller and report slot counts "
               "(on time / late / missed / failed), the lateness distribution (p50, p99, p99.9, max in us), the CPU "
               "the sampler used and whether SCHED_FIFO and pinning were applied. --load adds competing CPU load.")

# Competing load: a 16 MB memmove (memory bandwidth, cache eviction) then pure-Python
# arithmetic, until the bench is gone. Normal priority, no affinity.
LOAD_CODE = ("import os, sys\nparent = int(sys.argv[1])\nbuf = bytearray(16 << 20)\n"
             "while os.getppid() == parent:\n    buf[1:] = buf[:-1]\n    sum(range(200_000))\n")


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seconds", type=float, default=10.0, help="duration of the run (default 10)")
    p.add_argument("--rate-hz", type=float, default=1000.0, help="slot rate (default 1000)")
    p.add_argument("--block-size", type=int, default=10, help="samples per block (default 10)")
    p.add_argument("--load", type=int, nargs="?", const=os.cpu_count() or 1, default=0, metavar="N",
                   help="N competing load processes (--load alone: one per CPU; default none)")
    p.add_argument("--read-us", type=float, default=0.0,
                   help="busy wait per read in the synthetic poller, standing in for I/O time (default 0)")
    p.add_argument("--rt-priority", type=int, default=40, help="SCHED_FIFO priority; 0: normal scheduling (default 40)")
    p.add_argument("--spin-us", type=float, default=None,
                   help="sleep until this long before each deadline, then spin (default: the sampler's default)")
    p.add_argument("--cpu", default="auto", help="CPU to pin to: auto (the last one), none, or a number (default auto)")
    p.add_argument("--json", action="store_true")


def _machine() -> dict:
    model = "unknown"
    try:
        with open("/proc/cpuinfo") as f:
            model = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), model)
    except OSError:
        pass
    return {"cpu_model": model, "cpus": os.cpu_count(), "kernel": platform.release(),
            "python": platform.python_version(), "machine": platform.machine()}


def _steal_ticks() -> dict[str, int]:
    """Time the hypervisor gave our vCPUs to someone else, in clock ticks: "cpu" for all
    CPUs, "cpuN" for each."""
    out = {}
    try:
        with open("/proc/stat") as f:
            for line in f:
                fields = line.split()
                if fields and fields[0].startswith("cpu") and len(fields) > 8:
                    out[fields[0]] = int(fields[8])
    except (OSError, ValueError):
        pass
    return out


async def _measure(cfg, seconds: float) -> tuple[dict, np.ndarray, np.ndarray]:
    """Run for ``seconds`` of slots; returns what the source reported, and per sample
    the lateness and the lateness of the wake-up that led to it (s)."""
    from fluidsense.drivers.sampler import SampledSource

    src = SampledSource(cfg)
    t: list[np.ndarray] = []
    lateness: list[np.ndarray] = []
    async with src:
        hello = src.hello
        target = int(seconds * cfg.rate_hz)
        while src.stats["slots"] < target:
            block = await src.read_block()
            t.append(block.t)
            lateness.append(block.lateness_s)
    got = {"hello": hello, "final": src.final, "stats": dict(src.stats),
           "stall_total_s": sum(s for _, s in src.stall_log)}
    if not t:
        return got, np.empty(0), np.empty(0)
    lat = np.concatenate(lateness)
    slots = np.round((np.concatenate(t) - lat) * cfg.rate_hz).astype(np.int64)
    # a sample served after a stall was preceded by a wake-up later than one period:
    # that wake-up's lateness is what a plain "how late did the loop wake" measure sees
    stall = dict(src.stall_log)
    wake = np.array([stall.get(int(k), x) for k, x in zip(slots, lat)])
    return got, lat, wake


def run(args: argparse.Namespace) -> int:
    from fluidsense.drivers.sampler import SamplerConfig

    cpu = args.cpu if args.cpu in ("auto", "none") else int(args.cpu)
    cfg = SamplerConfig(
        poller={"factory": "fluidsense.drivers.sampler.synthetic:SyntheticPoller", "kwargs": {"busy_us": args.read_us}},
        channels=("p_act",), rate_hz=args.rate_hz, block_size=args.block_size, cpu=cpu,
        rt_priority=args.rt_priority or None, **({} if args.spin_us is None else {"spin_us": args.spin_us}))
    loads = [subprocess.Popen([sys.executable, "-c", LOAD_CODE, str(os.getpid())]) for _ in range(args.load)]
    steal0, wall0 = _steal_ticks(), time.monotonic()
    try:
        got, lateness, wake = asyncio.run(_measure(cfg, args.seconds))
    finally:
        for proc in loads:
            proc.kill()
            proc.wait()
    steal1, wall1 = _steal_ticks(), time.monotonic()
    out = _report(args, cfg, got, lateness, wake)
    out.update(_steal(steal0, steal1, wall1 - wall0, got["hello"]["realtime"]["affinity"].get("cpu")))
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        _print(out)
    return 0


def _percentiles_us(x_s: np.ndarray) -> dict:
    if not len(x_s):
        return {}
    x = x_s * 1e6
    out = {name: float(np.percentile(x, q)) for name, q in (("p50", 50), ("p99", 99), ("p99.9", 99.9))}
    out["max"] = float(x.max())
    return out


def _steal(before: dict[str, int], after: dict[str, int], wall_s: float, pinned: int | None) -> dict:
    """Steal during the run: to compare with the stalls, since a vCPU that the host
    deschedules stalls even a SCHED_FIFO thread."""
    hz = os.sysconf("SC_CLK_TCK")
    out = {}
    if "cpu" in before and "cpu" in after:
        out["steal_pct_of_all_cpus"] = 100.0 * (after["cpu"] - before["cpu"]) / hz / (wall_s * (os.cpu_count() or 1))
    key = f"cpu{pinned}"
    if pinned is not None and key in before and key in after:
        out["steal_ms_on_sampler_cpu"] = 1e3 * (after[key] - before[key]) / hz
    return out


def _report(args: argparse.Namespace, cfg, got: dict, lateness: np.ndarray, wake: np.ndarray) -> dict:
    final = got["final"] or {}
    lat_us = lateness * 1e6
    cpu = final.get("cpu", {})
    wall = cpu.get("wall_s") or float("nan")
    realtime = got["hello"]["realtime"]
    return {
        "machine": _machine(),
        "run": {"seconds": args.seconds, "rate_hz": cfg.rate_hz, "block_size": cfg.block_size,
                "load_processes": args.load, "read_us": args.read_us, "late_threshold_us": cfg.late_threshold_us,
                "spin_us": cfg.spin_us, "rt_priority": cfg.rt_priority, "cpu": cfg.cpu},
        "applied": {k: v["applied"] for k, v in realtime.items()},
        "applied_detail": {k: v["detail"] for k, v in realtime.items()},
        "slots": final.get("totals"),
        "dropped_in_transit": got["stats"]["dropped"],
        "samples": int(len(lat_us)),
        "lateness_us": _percentiles_us(lateness),
        "wake_lateness_us": _percentiles_us(wake),
        "stalls": got["stats"]["stalls"], "stall_max_us": got["stats"]["stall_max_s"] * 1e6,
        "stall_total_ms": got["stall_total_s"] * 1e3,
        "late_over_100us": int(np.sum(lat_us > 100)), "late_over_1ms": int(np.sum(lat_us > 1000)),
        "sampler_cpu": {**cpu, "process_cpu_pct": 100.0 * cpu.get("process_cpu_s", float("nan")) / wall,
                        "loop_thread_cpu_pct": 100.0 * cpu.get("loop_thread_cpu_s", float("nan")) / wall},
        "stop": final.get("reason"),
    }


def _print(out: dict) -> None:
    r, m, a = out["run"], out["machine"], out["applied"]
    print(f"machine: {m['cpu_model']}, {m['cpus']} CPUs, Linux {m['kernel']}, Python {m['python']}")
    print(f"run: {r['seconds']:g} s at {r['rate_hz']:g} Hz, blocks of {r['block_size']}, synthetic poller "
          f"(read {r['read_us']:g} us), load processes: {r['load_processes']}")
    print("applied: " + ", ".join(f"{k} {'yes' if v else 'no'}" for k, v in a.items()))
    for k, v in out["applied_detail"].items():
        if not a[k]:
            print(f"  {k}: {v}")
    s = out["slots"] or {}
    print(f"slots {s.get('slots')}: on time {s.get('on_time')}, "
          f"late {s.get('late')} (> {r['late_threshold_us']:g} us), "
          f"missed {s.get('missed')}, failed {s.get('failed')}; dropped in transit {out['dropped_in_transit']}")
    p = out["lateness_us"]
    if p:
        print(f"lateness (us, {out['samples']} samples): p50 {p['p50']:.2f}  p99 {p['p99']:.2f}  "
              f"p99.9 {p['p99.9']:.1f}  max {p['max']:.1f};  > 100 us: {out['late_over_100us']}, "
              f"> 1 ms: {out['late_over_1ms']}")
        w = out["wake_lateness_us"]
        print(f"wake-up lateness (us, stalls included): p50 {w['p50']:.2f}  p99 {w['p99']:.2f}  "
              f"p99.9 {w['p99.9']:.1f}  max {w['max']:.1f};  stalls (woke after the next deadline): "
              f"{out['stalls']}, longest {out['stall_max_us'] / 1e3:.2f} ms")
    c = out["sampler_cpu"]
    if c.get("wall_s"):
        print(f"sampler CPU: {c['process_cpu_pct']:.1f} % of one CPU (loop thread {c['loop_thread_cpu_pct']:.1f} %), "
              f"context switches {c['voluntary_switches']} voluntary / {c['involuntary_switches']} involuntary, "
              f"page faults {c['minor_faults']} minor / {c['major_faults']} major")
    if "steal_pct_of_all_cpus" in out:
        line = f"hypervisor steal during the run: {out['steal_pct_of_all_cpus']:.2f} % of all CPUs"
        if "steal_ms_on_sampler_cpu" in out:
            line += (f", {out['steal_ms_on_sampler_cpu']:.0f} ms on the sampler's CPU "
                     f"(stalls total {out['stall_total_ms']:.1f} ms)")
        print(line)
