"""``python -m lab bench soak``: hours of back-to-back cycles in virtual time, slow subscriber attached.

The controller runs in this process on the simulated cell (virtual time: as fast as the
CPU allows) with a real ZeroMQ publisher on an ipc:// endpoint and, as the daemon does,
a recording (into a temporary directory, deleted afterwards: its size is reported; or
``--no-record``). A subscriber in another process reads every topic and sleeps between
messages, so it falls behind: the publisher's queue for it fills to the high-water mark
and PUB drops what does not fit, by design. After a free-air reference cycle the cell
grips each scene of ``SCENES`` in turn, cycle after cycle, until the sample time reaches
``--virtual-hours``. Reported (docs/soak.md explains each figure):

- ``samples_lost`` / ``duplicated``: sample slots the source produced that did not reach
  the controller's pipeline (or reached it twice): block-number and sample-slot gaps, and
  slots the source itself reported missed. Must be 0.
- ``subscriber``: what the slow subscriber got: messages, the ones PUB dropped for it
  (gaps in the envelope's ``seq``), pressure samples and duplicates among them.
- ``rss_start_mb`` -> ``rss_end_mb``: resident memory (/proc/self/statm) after warm-up
  (the first ``window_h`` of sample time, in which the publisher's queue fills) and at
  the end; ``memory_growth_mb`` is the difference (target <= 10 MB).
- ``drift``: per scene, P_eq's mean over the first ``window_h`` against the last, in kPa
  and in sensor-noise sd, with the slope over the run and its standard error.
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import json
import multiprocessing
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from fluidsense.controller.service import Sink
from fluidsense.common.names import welcome_instance

NAME = "soak"
HELP = "hours of cycles in virtual time with a slow subscriber: samples lost, memory growth, drift"
DESCRIPTION = __doc__
HOUR = 3600.0
END_MARK = "soak finished"
# free air, the paper's 60 mm cylinder, a 40 x 100 mm block: three plateaus of P_eq
SCENES = {"none": {"kind": "none"}, "cylinder-60": {"kind": "cylinder", "diameter_mm": 60},
          "rectangle-40": {"kind": "rectangle", "width_mm": 40}}
PAGE_MB = os.sysconf("SC_PAGE_SIZE") / 2**20


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("--virtual-hours", type=float, default=8.0, help="sample time to run (default 8 h)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--sub-delay-ms", type=float, default=10.0,
                   help="the slow subscriber sleeps this long after each message (default 10 ms)")
    p.add_argument("--pub-hwm", type=int, default=None,
                   help="publisher high-water mark in messages (default: the daemon's)")
    p.add_argument("--no-record", action="store_true", help="do not record (default: record to a temporary dir)")
    p.add_argument("--config", "-c", help="cell config with driver: sim (default: config/cell-sim.yaml)")
    p.add_argument("--json", action="store_true")


class GapCounter(Sink):
    """Checks that every sample the source produced reached the controller's pipeline
    once: consecutive block numbers, consecutive sample slots, no slot reported missed."""

    def __init__(self, rate_hz: float):
        self.rate_hz = rate_hz
        self.blocks = 0
        self.samples = 0
        self.block_gaps = 0  # blocks missing between consecutive block numbers
        self.slot_gaps = 0  # sample slots skipped between or within blocks
        self.duplicated = 0  # sample slots seen again (time not moving forward)
        self.missed = 0  # slots the source itself reported unfilled
        self._seq: int | None = None
        self._slot: int | None = None

    def on_block(self, block) -> None:
        slots = np.rint(np.asarray(block.t) * self.rate_hz).astype(np.int64)
        if self._seq is not None:
            self.block_gaps += max(block.seq - self._seq - 1, 0)
        steps = np.diff(slots) if self._slot is None else np.diff(slots, prepend=self._slot)
        self.slot_gaps += int(np.clip(steps - 1, 0, None).sum())
        self.duplicated += int(np.clip(1 - steps, 0, None).sum())
        self._seq, self._slot = block.seq, int(slots[-1])
        self.blocks += 1
        self.samples += len(block)
        self.missed += block.missed

    @property
    def lost(self) -> int:
        return self.slot_gaps + self.missed


def rss_mb() -> float:
    """Resident set size of this process (second field of /proc/self/statm, in pages)."""
    return int(Path("/proc/self/statm").read_text().split()[1]) * PAGE_MB


def _slow_subscriber(endpoint: str, rate_hz: float, delay_s: float, attached, drain, caught_up,
                     conn) -> None:  # pragma: no cover - runs in the child process
    """Another process: read everything, slowly, until the end mark; report what arrived.
    Once ``drain`` is set it reads at full speed and says when its queue is empty."""
    import zmq

    ctx = zmq.Context()
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.LINGER, 0)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    sub.connect(endpoint)
    got = {"received": 0, "dropped": 0, "first_seq": None, "last_seq": None, "pressure_samples": 0,
           "pressure_duplicated": 0, "ended": False}
    last_slot = None
    quiet_deadline = None
    while True:
        if not sub.poll(200):
            if drain.is_set():
                caught_up.set()
                quiet_deadline = quiet_deadline or time.monotonic() + 120
                if time.monotonic() > quiet_deadline:
                    break  # the end mark never came: report what did
            continue
        frames = sub.recv_multipart()
        if welcome_instance(frames) is not None:
            attached.set()
            continue
        msg = json.loads(frames[1])
        seq = msg["seq"]
        if got["last_seq"] is None:
            got["first_seq"] = seq
        else:
            got["dropped"] += max(seq - got["last_seq"] - 1, 0)
        got["last_seq"] = seq
        got["received"] += 1
        if msg["topic"] == "pressure":
            slots = np.rint(np.asarray(msg["times_s"]) * rate_hz).astype(np.int64)
            steps = np.diff(slots) if last_slot is None else np.diff(slots, prepend=last_slot)
            got["pressure_duplicated"] += int(np.clip(1 - steps, 0, None).sum())
            got["pressure_samples"] += msg["n"]
            last_slot = int(slots[-1])
        if msg["topic"] == "log" and msg["message"] == END_MARK:
            got["ended"] = True
            break
        if not drain.is_set():
            time.sleep(delay_s)  # the load: a consumer slower than the producer
    conn.send(got)
    sub.close()
    ctx.term()


def _by_hour(rss: list[tuple[float, float]]) -> list[list[float]]:
    """The first RSS reading in each hour of sample time: [hour, MB], to see a plateau."""
    out: dict[int, float] = {}
    for t_h, mb in rss:
        out.setdefault(int(t_h), mb)
    return [[h, round(mb, 2)] for h, mb in sorted(out.items())]


def _fit(t_h: np.ndarray, y: np.ndarray) -> dict[str, float | None]:
    """Least-squares slope (per hour) and its standard error."""
    if len(y) < 3 or np.ptp(t_h) == 0:
        return {"slope_per_h": None, "slope_se_per_h": None}
    (slope, _), cov = np.polyfit(t_h, y, 1, cov=True)
    return {"slope_per_h": float(slope), "slope_se_per_h": float(np.sqrt(cov[0, 0]))}


def drift(rows: list[tuple[str, float, float | None]], window_h: float, noise_sd_kpa: float) -> dict[str, Any]:
    """Per scene: P_eq's mean over the first and the last ``window_h`` hours of the run."""
    t_all = np.array([r[1] for r in rows]) / HOUR
    t0, t1 = t_all.min(), t_all.max()
    out: dict[str, Any] = {}
    for scene in dict.fromkeys(r[0] for r in rows):
        t = np.array([r[1] for r in rows if r[0] == scene]) / HOUR
        y = np.array([np.nan if r[2] is None else r[2] for r in rows if r[0] == scene], dtype=float)
        ok = np.isfinite(y)
        first, last = y[ok & (t <= t0 + window_h)], y[ok & (t >= t1 - window_h)]
        diff = float(last.mean() - first.mean()) if len(first) and len(last) else None
        out[scene] = {"cycles": int(ok.sum()), "first_n": len(first), "last_n": len(last),
                      "p_eq_first_mean_kpa": float(first.mean()) if len(first) else None,
                      "p_eq_last_mean_kpa": float(last.mean()) if len(last) else None,
                      "last_minus_first_kpa": diff,
                      "last_minus_first_noise_sd": None if diff is None else diff / noise_sd_kpa,
                      "cycle_sd_kpa": float(y[ok].std(ddof=1)) if ok.sum() > 1 else None,
                      **_fit(t[ok], y[ok])}
    return out


class _Subscriber:
    """The slow subscriber's process and the events it is driven by."""

    def __init__(self, endpoint: str, rate_hz: float, delay_s: float):
        mp = multiprocessing.get_context("spawn")  # no fork of a process holding ZeroMQ sockets
        self.attached, self.drain, self.caught_up = mp.Event(), mp.Event(), mp.Event()
        self._recv, send = mp.Pipe(duplex=False)
        self.proc = mp.Process(target=_slow_subscriber, daemon=True, name="soak-slow-subscriber",
                               args=(endpoint, rate_hz, delay_s, self.attached, self.drain, self.caught_up, send))
        self.proc.start()

    async def finish(self, ctrl) -> dict[str, Any] | None:
        """Let it catch up, send the end mark, and collect its report."""
        self.drain.set()
        await asyncio.to_thread(self.caught_up.wait, 300)
        ctrl.emit("log", {"level": "INFO", "message": END_MARK})
        ready = await asyncio.to_thread(self._recv.poll, 180)
        return self._recv.recv() if ready else None

    def stop(self) -> None:
        self.proc.join(timeout=10)
        if self.proc.is_alive():
            self.proc.terminate()


async def _cycles(ctrl, end_s: float, window_h: float) -> tuple[list, dict, list]:
    """Cycle through the scenes until ``end_s`` of sample time; memory after warm-up."""
    from fluidsense.common.scenes import Scene
    from pydantic import TypeAdapter

    parse_scene = TypeAdapter(Scene).validate_python
    await ctrl.scene.place(parse_scene(SCENES["none"]))
    await ctrl.run_cycle(store_reference=True)
    rows, rss, warm = [], [], None
    names = list(SCENES)
    while ctrl.now < end_s:
        scene = names[len(rows) % len(names)]
        await ctrl.scene.place(parse_scene(SCENES[scene]))
        res = await ctrl.run_cycle(label=scene)
        rows.append((scene, res.t_start, res.to_dict()["p_eq_kpa"], res.ok))  # as the cycle publishes it
        if warm is None and ctrl.now >= window_h * HOUR:
            gc.collect()
            warm = {"rss_mb": rss_mb(), "objects": len(gc.get_objects()), "cycles": len(rows)}
        if warm is not None:
            rss.append((ctrl.now / HOUR, rss_mb()))
    return rows, warm, rss


async def _soak(cfg, hours: float, delay_s: float, record: bool, pub_hwm: int | None) -> dict[str, Any]:
    from fluidsense.daemon import app

    rss0 = rss_mb()
    wall0 = time.perf_counter()
    end_s, window_h = hours * HOUR, min(1.0, hours / 4)
    async with app.controller(cfg, publish=True, record=record, pub_hwm=pub_hwm) as ctrl:
        gaps = GapCounter(ctrl.backend.source.rate_hz)
        ctrl.add_sink(gaps)
        sub = _Subscriber(cfg.publisher.pub, ctrl.backend.source.rate_hz, delay_s)
        try:
            if not await asyncio.to_thread(sub.attached.wait, 60):
                raise RuntimeError("the slow subscriber did not attach within 60 s")
            rows, warm, rss = await _cycles(ctrl, end_s, window_h)
            gc.collect()
            end = {"rss_mb": rss_mb(), "objects": len(gc.get_objects())}
            wall = time.perf_counter() - wall0
            seen = await sub.finish(ctrl)
            status = ctrl.status()
        finally:
            sub.stop()
    noise_sd = cfg.profile.sensor.noise_sd_kpa
    return {
        "virtual_hours": ctrl.now / HOUR, "wall_s": wall, "speedup": ctrl.now / wall,
        "cycles": len(rows), "cycles_failed": sum(not r[3] for r in rows),
        "samples": gaps.samples, "samples_lost": gaps.lost, "duplicated": gaps.duplicated,
        "blocks": gaps.blocks, "block_gaps": gaps.block_gaps, "source_missed": gaps.missed,
        "controller_samples": status["samples"],
        "rss_initial_mb": rss0, "rss_start_mb": warm["rss_mb"] if warm else None, "rss_end_mb": end["rss_mb"],
        "memory_growth_mb": end["rss_mb"] - warm["rss_mb"] if warm else None,
        "rss_max_mb": max((r for _, r in rss), default=end["rss_mb"]),
        "warmup_h": window_h, "warmup_cycles": warm["cycles"] if warm else None, "rss_by_hour": _by_hour(rss),
        "py_objects": {"start": warm["objects"] if warm else None, "end": end["objects"]},
        "subscriber": None if seen is None else {
            "delay_ms": delay_s * 1e3, "pub_hwm": pub_hwm or cfg.publisher.hwm_messages, "received": seen["received"], "dropped": seen["dropped"],
            "published_since_attach": None if seen["first_seq"] is None else seen["last_seq"] - seen["first_seq"] + 1,
            "pressure_samples": seen["pressure_samples"], "pressure_duplicated": seen["pressure_duplicated"],
            "got_end_mark": seen["ended"]},
        "noise_sd_kpa": noise_sd, "drift_window_h": window_h,
        "drift": drift([r[:3] for r in rows if r[3]], window_h, noise_sd) if rows else None,
    }


def _recording_size(root: Path) -> dict[str, Any]:
    files = sorted(root.rglob("*.mcap"))
    return {"files": len(files), "bytes": sum(f.stat().st_size for f in files)}


def run_soak(hours: float, seed: int = 1, delay_ms: float = 10.0, config: str | None = None,
             record: bool = True, pub_hwm: int | None = None) -> dict[str, Any]:
    from fluidsense.daemon import app

    tmp = Path(tempfile.mkdtemp(prefix="fluidsense-soak-"))
    cfg = app.load(config, {"driver": {"clock": "virtual", "seed": seed},
                            "publisher": {"pub": f"ipc://{tmp}/pub", "cmd": f"ipc://{tmp}/cmd"},
                            "recording": {"dir": str(tmp / "runs"), "min_free_mb": 64}})
    try:
        out = asyncio.run(_soak(cfg, hours, delay_ms / 1e3, record, pub_hwm))
        rec = _recording_size(tmp / "runs") if record else None
        return {"seed": seed, **out, "recording": rec}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def run(args: argparse.Namespace) -> int:
    out = run_soak(args.virtual_hours, args.seed, args.sub_delay_ms, args.config, not args.no_record, args.pub_hwm)
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    print(f"{out['virtual_hours']:.2f} virtual hours in {out['wall_s']:.0f} s wall ({out['speedup']:.0f}x), "
          f"{out['cycles']} cycles ({out['cycles_failed']} failed), {out['samples']} samples")
    sub = out["subscriber"] or {}
    print(f"samples lost: {out['samples_lost']}, duplicated: {out['duplicated']}; "
          f"slow subscriber got {sub.get('received')} messages, PUB dropped {sub.get('dropped')} for it")
    if out["memory_growth_mb"] is not None:
        print(f"RSS {out['rss_start_mb']:.1f} MB after warm-up -> {out['rss_end_mb']:.1f} MB "
              f"(growth {out['memory_growth_mb']:+.2f} MB, max {out['rss_max_mb']:.1f} MB)")
    for scene, d in (out["drift"] or {}).items():
        if d["last_minus_first_kpa"] is not None:
            print(f"{scene}: P_eq {d['p_eq_first_mean_kpa']:.3f} -> {d['p_eq_last_mean_kpa']:.3f} kPa "
                  f"({d['last_minus_first_kpa']:+.4f} kPa, {d['last_minus_first_noise_sd']:+.2f} noise sd)")
    if out["recording"]:
        print(f"recording: {out['recording']['files']} files, {out['recording']['bytes'] / 2**20:.1f} MB")
    return 0
