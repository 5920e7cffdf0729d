"""``python -m lab bench timing``: the daemon at 1 kHz, measured from another process.

Starts ``fluidsense run`` (real time) on the simulated cell (``--source sim``: hardware-
timed, exact timestamps), on a polled Modbus analog input served by the emulated UR
control box (``--source modbus``: the sampler process polls it), on the ur driver against
the same emulated box (``--source ur``: the sampler takes ur_rtde's newest RTDE package
each slot, a slot without a new one is missed; the ur_rtde worker runs beside it as
shipped), or on the serial driver
against the firmware's host board behind a pty, fed by the simulated cell (``--source
serial``: ``python -m lab simserial``; hardware-timed by the board's timer, each sample
stamped from its device tick), attaches a ZeroMQ subscriber in this process and
reports, for the samples it received:
- lost and duplicated samples (every slot of the grid accounted for),
- lateness of each sample's timestamp against its slot (0 for a hardware-timed source),
- end-to-end latency from a sample's timestamp to its arrival here (CLOCK_MONOTONIC is
  shared by the processes of a machine): the newest sample of each published block,
- CPU used by the daemon and its sampler process (and, for serial, by the simulated
  device: the board process and the plant, which a real device does not take);
- for serial, the link's counts from the daemon (frames lost and corrupt, retries,
  clock offset and drift) and the board's (its timer's wake-up lateness, ticks whose
  plant inputs came late, frames it dropped); for the AVR image, its CPU budget per
  sample in AVR cycles by part (timer, ADC and USART interrupts, framing and CRC), the
  link's bytes against its baud rate, and the latencies it measures in its own cycles
  (a valve command's last byte to the pins with ``--cycles``; at the end the daemon is
  killed, and the heartbeat's last frame to the vent on the pins).
Blocks are published as they come (``pressure_batch_s`` = one block). The daemon records
as it does in production (MCAP, flushed every second), into the benchmark's temporary
directory, which is removed at the end; ``--no-record`` measures without it.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml
import zmq
from fluidsense.common.names import welcome_instance

NAME = "timing"
HELP = "1 kHz end to end: lost samples, lateness, latency to a subscriber, CPU"
DESCRIPTION = __doc__


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seconds", type=float, default=60.0, help="measurement length (default 60)")
    p.add_argument("--source", choices=["sim", "modbus", "ur", "serial"], default="sim")
    p.add_argument("--board", choices=["host", "avr"], default="host",
                   help="serial: the host board (default) or the AVR image in simavr")
    p.add_argument("--cycles", action="store_true",
                   help="ask the daemon for a gripper cycle every 5 s during the run (valve commands)")
    p.add_argument("--reader", choices=["thread", "loop"], default=None,
                   help="serial: the driver's reader (default: the config's, thread)")
    p.add_argument("--rate-hz", type=float, default=None,
                   help="default 1000; modbus: 500 (an e-Series box refreshes its registers no faster)")
    p.add_argument("--load", nargs="?", const=-1, type=int, default=0,
                   help="competing CPU load: N busy processes (default: one per CPU)")
    p.add_argument("--late-us", type=float, default=50.0, help="a sample this late is late (default 50 us)")
    p.add_argument("--no-record", dest="record", action="store_false",
                   help="run the daemon without its recording (default: records, as in production)")
    p.add_argument("--json", action="store_true")


def _burn(stop_at: float) -> None:  # pragma: no cover - runs in a load process
    x = 0
    while time.monotonic() < stop_at:
        x += 1


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process and its live children (Linux /proc)."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0.0
    pids = [pid]
    try:
        for task in Path(f"/proc/{pid}/task").iterdir():
            kids = (task / "children").read_text().split()
            pids += [int(k) for k in kids]
    except OSError:
        pass
    for p in pids:
        try:
            fields = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / tick
        except (OSError, IndexError, ValueError):
            pass
    return total


def _cell_config(tmp: Path, source: str, rate: float, record: bool = True, reader: str | None = None) -> Path:
    from lab import REPO

    block = 10
    data: dict[str, Any] = {
        "profile": str(REPO / "config" / "profiles" / "pneunet-gripper.yaml"),
        "publisher": {"pub": f"ipc://{tmp}/pub", "cmd": f"ipc://{tmp}/cmd", "pressure_batch_s": block / rate},
        "log_level": "WARNING",
        "recording": {"enabled": record, "dir": str(tmp / "runs"), "min_free_mb": 16},
    }
    if source == "sim":
        data["driver"] = {"kind": "sim", "clock": "realtime", "rate_hz": rate, "block_size": block, "seed": 1}
    elif source == "serial":
        cell = yaml.safe_load((REPO / "config" / "cell-serial-sim.yaml").read_text())
        driver = {**cell["driver"], "port": str(tmp / "device.tty"), "rate_hz": int(rate)}
        driver.pop("sim_control_port", None)
        if reader is not None:
            driver["reader"] = reader
        data["driver"] = driver
        data["profile"] = str(REPO / "config" / cell["profile"])
    elif source == "ur":
        # the whole ur driver as shipped (the sampler's RTDE receive, the ur_rtde worker with
        # its own RTDE streams and the box's watchdog), on a free loopback address: ur_rtde's
        # ports are fixed and other boxes may run on this machine
        from fluidsense.simulator.controlbox.process import free_loopback

        cell = yaml.safe_load((REPO / "config" / "cell-ur-sim.yaml").read_text())
        data["driver"] = {**cell["driver"], "host": free_loopback(), "rate_hz": rate}
        data["driver"].pop("sim_control_port", None)
        data["profile"] = str((REPO / "config" / cell["profile"]).resolve())
    else:
        modbus = REPO / "config" / "cell-modbus-sim.yaml"
        if not modbus.exists():
            raise SystemExit("--source modbus needs the Modbus driver (config/cell-modbus-sim.yaml)")
        cell = yaml.safe_load(modbus.read_text())
        # daemon and sampler only: the arm's ur_rtde worker (and its own 500 Hz RTDE
        # stream) is not part of the sampling path being measured
        data["driver"] = {**cell["driver"], "arm": None, "rate_hz": rate}
        data["profile"] = str((modbus.parent / cell["profile"]).resolve()) if isinstance(cell["profile"], str) \
            else cell["profile"]
    path = tmp / "cell.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _first_pressure(sub, timeout_s: float) -> tuple[list[bytes], float]:
    """The first ``pressure`` message and when it came (other topics before it are dropped)."""
    deadline = time.monotonic() + timeout_s
    while (left := deadline - time.monotonic()) > 0:
        if sub.poll(int(left * 1000)):
            frames = sub.recv_multipart()
            if frames[0] == b"pressure":
                return frames, time.monotonic()
    raise RuntimeError(f"no samples within {timeout_s:g} s of the daemon's welcome")


def run_bench(seconds: float = 60.0, source: str = "sim", rate: float = 1000.0, load: int = 0,
              late_us: float = 50.0, record: bool = True, reader: str | None = None, board: str = "host",
              cycles: bool = False) -> dict[str, Any]:
    tmp = Path(tempfile.mkdtemp(prefix="fluidsense-timing-"))
    try:
        cfg = _cell_config(tmp, source, rate, record, reader)
        res = _measure(tmp, cfg, seconds, source, rate, load, late_us, record, board, cycles)
        if source == "serial":
            driver = yaml.safe_load(cfg.read_text())["driver"]
            res["reader"] = driver.get("reader", "thread")
            res["board_kind"] = board
            if board == "avr" and res["board"]:
                res["avr"] = avr_budget(res["board"], rate, len(driver["wiring"]["sensors"]), driver["baudrate"])
        return res
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _measure(tmp: Path, cfg: Path, seconds: float, source: str, rate: float, load: int, late_us: float,
             record: bool, board: str = "host", cycles: bool = False) -> dict[str, Any]:
    extra: list[subprocess.Popen] = []
    rtt = device = None
    kill_at_end = source == "serial" and board == "avr"  # then the board measures its heartbeat watchdog
    if source == "serial":
        device = subprocess.Popen([sys.executable, "-m", "lab", "simserial", "--config", str(cfg), "--board", board],
                                  stdin=subprocess.DEVNULL, stdout=subprocess.PIPE)
        extra.append(device)
        ready = select.select([device.stdout], [], [], 60)[0] and device.stdout.readline().decode()
        if not ready or not ready.startswith("ready"):
            device.kill()
            raise RuntimeError(f"python -m lab simserial did not start (said {ready!r})")
    if source in ("modbus", "ur"):
        box = subprocess.Popen([sys.executable, "-m", "fluidsense", "simcell", "--config", str(cfg)],
                               stdout=subprocess.PIPE)
        extra.append(box)
        ready = select.select([box.stdout], [], [], 30)[0] and box.stdout.readline().decode()
        if not ready or not ready.startswith("ready"):
            box.kill()
            raise RuntimeError(f"fluidsense simcell did not start (said {ready!r}); is another box on its ports?")
        rtt = _modbus_read_times(cfg) if source == "modbus" else None
    daemon = subprocess.Popen([sys.executable, "-m", "fluidsense", "run", "--config", str(cfg)],
                              stderr=subprocess.PIPE, start_new_session=kill_at_end)
    ctx = zmq.Context()
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.RCVHWM, 100_000)
    for topic in (b"pressure", b"hello", b"fault"):
        sub.setsockopt(zmq.SUBSCRIBE, topic)
    sub.connect(f"ipc://{tmp}/pub")
    burners: list[multiprocessing.Process] = []
    try:
        if not sub.poll(30_000) or welcome_instance(sub.recv_multipart()) is None:
            raise RuntimeError(f"the daemon did not come up: {daemon.stderr.read().decode()[-2000:]}")
        n_load = (os.cpu_count() or 1) if load == -1 else load
        # the measurement starts with the first sample, not the welcome: the daemon is up
        # before its sampler process is (about a second on a loaded 2-core machine), and a
        # window begun at the welcome counted that start-up as missing samples
        first = _first_pressure(sub, 30.0)
        stop_at = time.monotonic() + seconds
        for _ in range(n_load):
            pr = multiprocessing.Process(target=_burn, args=(stop_at,))
            pr.start()
            burners.append(pr)
        cpu0, wall0 = _cpu_s(daemon.pid), time.monotonic()
        dev_cpu0 = _cpu_s(device.pid) if device is not None else 0.0
        times, newest_age, oldest_age, in_daemon, faults = [], [], [], [], []

        def take(frames: list[bytes], arrival: float) -> None:
            msg = json.loads(frames[1])
            origin = msg["clock_origin_s"]
            t = msg["times_s"]
            times.extend(t)
            newest_age.append(arrival - (origin + t[-1]))
            in_daemon.append(msg["sent_s"] - (origin + t[-1]))
            oldest_age.append(arrival - (origin + t[0]))

        take(*first)
        next_cycle = time.monotonic() + 2.0 if cycles else float("inf")
        while time.monotonic() < stop_at:
            if time.monotonic() >= next_cycle:
                _request(ctx, tmp, {"cmd": "cycle"})  # refused while one runs: the next try is 5 s on
                next_cycle += 5.0
            if not sub.poll(1000):
                continue
            frames, arrival = sub.recv_multipart(), time.monotonic()
            if frames[0] == b"fault":  # e.g. overrun: the loop fell behind its samples
                fault = json.loads(frames[1])
                faults.append({"kind": fault["kind"], "detail": fault["detail"], "t_s": fault["t_s"]})
                _request(ctx, tmp, {"cmd": "reset"})  # measure on: the next cycles go on after it
            elif frames[0] == b"pressure":
                take(frames, arrival)
        cpu = (_cpu_s(daemon.pid) - cpu0) / (time.monotonic() - wall0)
        dev_cpu = (_cpu_s(device.pid) - dev_cpu0) / (time.monotonic() - wall0) if device is not None else None
        link = _status(ctx, tmp).get("source_link") if source == "serial" else None
    finally:
        for pr in burners:
            pr.join(5)
        if kill_at_end:  # no STOP, no heartbeat: the device's watchdog vents (measured in its cycles)
            os.killpg(daemon.pid, signal.SIGKILL)
            time.sleep(1.0)  # past the 0.5 s heartbeat timeout: the vent happens meanwhile
        daemon.send_signal(signal.SIGTERM)
        try:
            daemon.wait(30)
        except subprocess.TimeoutExpired:
            daemon.kill()
        board = None
        for p in extra:
            p.terminate()
            out, _ = p.communicate(timeout=30)
            if p is device:
                stats = [line[6:] for line in (out or b"").decode().splitlines() if line.startswith("stats ")]
                board = json.loads(stats[-1]).get("board") if stats else None
        sub.close()
        ctx.term()
    recorded = sum(f.stat().st_size for f in (tmp / "runs").glob("*.mcap"))
    t = np.array(times)
    if len(t) < 2:
        raise RuntimeError("the subscriber received no samples: see the daemon's log")
    # sample time 0 is slot 0's deadline and a sample is stamped when its read starts,
    # before the next slot's deadline: its slot is the floor (rounding would file a
    # sample more than half a period late under the next slot)
    k = np.floor(t * rate + 1e-6).astype(np.int64)
    lateness = (t - k / rate) * 1e6
    uniq = np.unique(k)
    pct = np.percentile
    newest_ms, in_daemon_ms = np.array(newest_age) * 1e3, np.array(in_daemon) * 1e3
    return {
        "source": source, "rate_hz": rate, "seconds": seconds, "load_processes": n_load, "samples": int(len(t)),
        "lost": int(uniq[-1] - uniq[0] + 1 - len(uniq)), "duplicated": int(len(k) - len(uniq)),
        "late_fraction": float(np.mean(lateness > late_us)), "late_threshold_us": late_us,
        "lateness_us": _pcts(lateness, p999=True),
        "e2e_latency_ms": _pcts(newest_ms),
        "e2e_latency_oldest_ms": {"p50": float(pct(oldest_age, 50) * 1e3), "p99": float(pct(oldest_age, 99) * 1e3)},
        # the newest sample's age split at the daemon's send: source + daemon, then ZeroMQ to here
        "to_daemon_send_ms": _pcts(in_daemon_ms),
        "daemon_send_to_subscriber_ms": _pcts(newest_ms - in_daemon_ms),
        "cpu_percent": 100.0 * cpu,
        "recording": record, "recorded_mb": recorded / 2**20,
        "modbus_read_us": rtt, "faults": faults,
        **({"device_cpu_percent": 100.0 * dev_cpu, "link": link, "board": board} if source == "serial" else {}),
    }


def _status(ctx: zmq.Context, tmp: Path) -> dict[str, Any]:
    """The daemon's status (its link counts), asked on its command socket."""
    return _request(ctx, tmp, {"cmd": "status"})


def _request(ctx: zmq.Context, tmp: Path, request: dict[str, Any]) -> dict[str, Any]:
    req = ctx.socket(zmq.REQ)
    req.setsockopt(zmq.LINGER, 0)
    req.connect(f"ipc://{tmp}/cmd")
    try:
        req.send(json.dumps(request).encode())
        return json.loads(req.recv()) if req.poll(10_000) else {}
    finally:
        req.close()


#: the AVR image's functions by part of a sample's cost (symbols of build/avr/fluidsense.elf)
AVR_PARTS = {
    "timer interrupt (10 kHz, starts the conversions)": ("__vector_7",),
    "ADC interrupt (one per channel)": ("__vector_21",),
    "USART interrupts (one per byte sent, per byte received)": ("__vector_19", "__vector_18"),
    "framing: sample frame, CRC, COBS, queueing": ("fs_core_tick", "send_payload", "fs_crc16", "fs_cobs_encode",
                                                   "fs_board_send", "flags", "header"),
    "commands: decoding, acks, outputs": ("fs_core_rx", "fs_cobs_decode", "send_ack", "send_info", "go_safe",
                                          "guard", "fs_board_outputs", "fs_board_aout", "fs_board_configure",
                                          "fs_core_init"),
    "main loop (copying the sample, watchdog, LED)": ("main",),
}


def avr_budget(board: dict[str, Any], rate: float, channels: int, baud: int) -> dict[str, Any]:
    """The AVR image's cost per sample from the simulated board's cycle counts: per tick of
    its sample timer (every tick sends a sample while a session streams; the seconds
    before the daemon's session, which cost less, are a few of the run's)."""
    f_cpu, samples = board["f_cpu"], max(1, board["ticks"])
    by_fn = board["cycles_by_function"]
    parts = {name: sum(by_fn.get(fn, 0) for fn in fns) / samples for name, fns in AVR_PARTS.items()}
    known = {fn for fns in AVR_PARTS.values() for fn in fns}
    parts["other (runtime library, start-up)"] = sum(v for fn, v in by_fn.items() if fn not in known) / samples
    period = f_cpu / rate
    awake = board["cycles"] - board["asleep"] - board["stalled"]
    frame_bytes = 19 + 2 * channels  # 15 + 2n payload, 2 CRC, 1 COBS, 1 delimiter
    return {
        "cycles_per_period": period,
        "cycles_per_sample": {k: round(v, 1) for k, v in parts.items()},
        "cycles_per_sample_total": round(sum(parts.values()), 1),
        "share_of_period": sum(parts.values()) / period,
        "awake_share": awake / board["cycles"],
        "frame_bytes": frame_bytes,
        "link_bytes_per_s": baud / 10,  # 8N1: ten bit times a byte
        "link_share": frame_bytes * rate / (baud / 10),
        "link_limit_hz": baud / 10 / frame_bytes,
        "tx_bytes_per_mcu_s": board["tx_bytes"] / (board["cycles"] / f_cpu),
    }


def _modbus_read_times(cfg: Path, n: int = 5000) -> dict[str, float]:
    """Round trip of one poll (every wired analog input in one request), before the daemon
    starts: the sampler's own poller code, here at normal priority in this process, paced
    at 1 kHz. The floor under any polled sample's latency."""
    from fluidsense.controller.config import load_cell_config
    from fluidsense.drivers.modbus.backend import modbus_domains, modbus_inputs
    from fluidsense.drivers.modbus.poller import ModbusAnalogPoller

    cell = load_cell_config(cfg)
    d, channels = cell.driver, cell.profile.hardware.channels
    poller = ModbusAnalogPoller(d.host, d.port, d.device_id, modbus_inputs(d, channels), d.timeout_s,
                                modbus_domains(d, channels))
    poller.open()
    took = np.empty(n)
    try:
        due = time.monotonic()
        for i in range(n):
            due += 1e-3
            time.sleep(max(0.0, due - time.monotonic()))
            t0 = time.perf_counter()
            poller.read()
            took[i] = time.perf_counter() - t0
    finally:
        poller.close()
    took *= 1e6
    return {"reads": n, **_pcts(took, p999=True),
            "over_1ms_fraction": float(np.mean(took > 1000.0))}


def _pcts(x: np.ndarray, p999: bool = False) -> dict[str, float]:
    out = {"p50": float(np.percentile(x, 50)), "p99": float(np.percentile(x, 99))}
    if p999:
        out["p999"] = float(np.percentile(x, 99.9))
    return {**out, "max": float(x.max())}


def run(args: argparse.Namespace) -> int:
    rate = args.rate_hz or (500.0 if args.source in ("modbus", "ur") else 1000.0)
    res = run_bench(args.seconds, args.source, rate, args.load, args.late_us, args.record, args.reader, args.board,
                    args.cycles)
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    lat, e2e = res["lateness_us"], res["e2e_latency_ms"]
    print(f"{res['source']} at {res['rate_hz']:.0f} Hz for {res['seconds']:.0f} s ({res['load_processes']} load "
          f"processes): {res['samples']} samples, {res['lost']} lost, {res['duplicated']} duplicated, "
          f"{100 * res['late_fraction']:.3f} % late; lateness p50/p99/p99.9/max {lat['p50']:.1f}/{lat['p99']:.1f}/"
          f"{lat['p999']:.1f}/{lat['max']:.1f} us; latency to subscriber p50/p99/max {e2e['p50']:.2f}/"
          f"{e2e['p99']:.2f}/{e2e['max']:.2f} ms; CPU {res['cpu_percent']:.1f} % of one core")
    for fault in res["faults"]:
        print(f"fault {fault['kind']} at {fault['t_s']:.3f} s: {fault['detail']}")
    if res["source"] == "serial":
        link, board = res["link"] or {}, res["board"] or {}
        wake = board.get("wake_late_us", {})
        print(f"serial ({res['reader']} reader): {link.get('frames')} frames, {link.get('lost_frames')} lost, "
              f"{link.get('corrupt_frames')} corrupt, {link.get('retries')} command retries, {link.get('resets')} "
              f"resets, clock drift {link.get('drift_ppm', 0.0):.1f} ppm; board: {board.get('ticks')} ticks, "
              f"{board.get('stale')} with late plant inputs, {board.get('skipped')} skipped, {board.get('tx_dropped')} "
              f"frames dropped, timer wake-up lateness p50/p99/max {wake.get('p50')}/{wake.get('p99')}/"
              f"{wake.get('max')} us; simulated device CPU {res['device_cpu_percent']:.1f} %")
    if res.get("avr"):
        avr, board = res["avr"], res["board"]
        print(f"AVR image: {avr['cycles_per_sample_total']:.0f} cycles per sample = "
              f"{100 * avr['share_of_period']:.1f} % of the {avr['cycles_per_period']:.0f} cycles of a period (awake "
              f"{100 * avr['awake_share']:.1f} %); link {avr['frame_bytes']} bytes per sample = "
              f"{100 * avr['link_share']:.1f} % of {avr['link_bytes_per_s']:.0f} bytes/s (limit "
              f"{avr['link_limit_hz']:.0f} Hz); on its TX line {board['samples_sent']} samples, "
              f"{board['seq_gaps']} seq gaps, {board['tick_gaps']} tick gaps, {board['bad_frames_out']} bad frames, "
              f"{board['flagged_tx_dropped']} TX_DROPPED, {board['flagged_adc_late']} ADC_LATE; MCU behind the clock "
              f"p99/max {board['lag_us']['p99']}/{board['lag_max_us']} us ({board['lag_over_100ms']} slices over "
              f"100 ms); SET_OUTPUTS last byte -> pins {board['set_outputs_to_pins_us']}; heartbeat -> vent "
              f"{board['heartbeat_to_vent_us']} us")
        for part, cycles in avr["cycles_per_sample"].items():
            print(f"  {cycles:8.1f} cycles  {part}")
    return 0
