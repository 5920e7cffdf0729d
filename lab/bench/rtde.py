"""``python -m lab bench rtde``: where the ur driver's missed slots go.

Starts ``fluidsense simcell`` (the emulated UR box, ``config/cell-ur-sim.yaml``) and runs,
in this process, the ur driver's RTDE poller in the sampler's own slot loop at 500 Hz
with the sampler's real-time settings (SCHED_FIFO 40 pinned to the last CPU, when
permitted), beside ``--load`` busy processes. It splits the missed slots into those whose
read found no new RTDE package (``NoNewSample``: the package was not there yet, or not yet
parsed by ur_rtde's receive thread) and those the loop itself reached too late, and says
whether the poller's threads (ur_rtde's receive thread) ran at the sampler's priority
(the driver's setting) or, with ``--normal-threads``, at normal priority (as before it).
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

import yaml

NAME = "rtde"
HELP = "the ur driver's RTDE poller in the slot loop: missed slots split into no new package and loop late"
DESCRIPTION = __doc__


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seconds", type=float, default=20.0, help="duration (default 20)")
    p.add_argument("--load", type=int, default=0, help="busy processes beside it (default 0)")
    p.add_argument("--normal-threads", action="store_true",
                   help="leave ur_rtde's receive thread at normal priority (the driver before this setting)")
    p.add_argument("--json", action="store_true")


def run_bench(seconds: float, load: int, fifo_threads: bool) -> dict[str, Any]:
    from fluidsense.controller.config import load_cell_config
    from fluidsense.drivers.sampler import realtime
    from fluidsense.drivers.sampler.poller import NoNewSample
    from fluidsense.drivers.sampler.slots import SlotLoop, SpinClock
    from fluidsense.drivers.ur.backend import rtde_inputs
    from fluidsense.drivers.ur.poller import RtdeAnalogPoller
    from fluidsense.simulator.controlbox.process import EmulatorProcess, free_loopback

    from lab import REPO

    with tempfile.TemporaryDirectory(prefix="fluidsense-bench-rtde-") as d:
        cell = yaml.safe_load((REPO / "config" / "cell-ur-sim.yaml").read_text())
        cell["driver"]["host"] = free_loopback()
        cell["profile"] = str(REPO / "config" / cell["profile"])
        cell["publisher"] = {"pub": f"ipc://{d}/pub", "cmd": f"ipc://{d}/cmd"}
        path = Path(d) / "cell.yaml"
        path.write_text(yaml.safe_dump(cell))
        box = EmulatorProcess(command=[sys.executable, "-m", "fluidsense", "simcell", "--config", str(path)])
        box.start(timeout_s=60)
        burners: list[subprocess.Popen] = []
        try:
            cfg = load_cell_config(path)
            rate = cfg.driver.rate_hz
            inputs = rtde_inputs(cfg.driver.wiring, cfg.profile.hardware.channels)
            poller = RtdeAnalogPoller(cfg.driver.host, rate, inputs)
            before = realtime.threads()
            poller.open()
            started = realtime.threads() - before
            no_new = [0]
            read = poller.read

            def counted() -> tuple[float, ...]:
                try:
                    return read()
                except NoNewSample:
                    no_new[0] += 1
                    raise

            poller.read = counted
            loop = SlotLoop(poller, SpinClock(75_000), lambda block: None, rate_hz=rate, block_size=5, n_channels=2,
                            late_threshold_ns=50_000, max_consecutive_failures=2, link_timeout_ns=250_000_000)
            # the busy processes first: started after, they would inherit this thread's SCHED_FIFO and CPU
            burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(load)]
            report = realtime.apply(40, "auto", poller_threads=started if fifo_threads else set())
            loadavg = Path("/proc/loadavg").read_text().split()[:3]
            end = time.monotonic() + seconds
            result = loop.run(lambda: time.monotonic() > end, time.monotonic_ns() + 10_000_000)
            poller.close()
        finally:
            for b in burners:
                b.kill()
                b.wait()
            box.stop()
            box.__exit__(None, None, None)
    totals = result.totals.as_dict()
    return {"seconds": seconds, "load": load, "rate_hz": rate, "slots": result.slots, **totals,
            "missed_no_new_package": no_new[0], "missed_loop_late": totals["missed"] - no_new[0],
            "poller_threads": len(started), "poller_threads_fifo": report["poller_threads"]["applied"],
            "sched_fifo": report["sched_fifo"]["applied"], "loadavg_at_start": loadavg}


def run(args: argparse.Namespace) -> int:
    res = run_bench(args.seconds, args.load, not args.normal_threads)
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    print(f"RTDE poller at {res['rate_hz']:.0f} Hz for {res['seconds']:.0f} s beside {res['load']} busy processes "
          f"(load average {' '.join(res['loadavg_at_start'])}; receive thread at "
          f"{'SCHED_FIFO' if res['poller_threads_fifo'] else 'normal priority'}): {res['slots']} slots, "
          f"{res['missed']} missed ({res['missed_no_new_package']} no new package, {res['missed_loop_late']} loop "
          f"late), {res['late']} late, {res['failed']} failed")
    return 0
