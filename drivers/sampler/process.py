"""Entry point of the sampler process: ``python -m fluidsense.drivers.sampler.process ARGS_JSON``.

Started (spawned, never forked) by :class:`drivers.sampler.source.SampledSource`.
ARGS_JSON is the validated SamplerConfig dumped to JSON plus ``data`` and ``control``
(ipc endpoints bound by the daemon), ``parent_pid`` and ``heartbeat_s``.

Order of start-up, and why:
1. ZeroMQ sockets first, so the I/O thread exists before the real-time settings and
   keeps the normal policy on any CPU (the settings are per thread);
2. the poller is built and opened (this may block on a network connect);
3. real-time settings (the threads the poller's open() started get SCHED_FIFO too: they
   receive what the loop reads), then ``hello`` (with what was applied), then the slot loop.

The process ends on a ``stop`` message, on SIGTERM (SIGINT is ignored: a Ctrl-C in
the daemon's terminal reaches the whole process group and the daemon stops us itself),
when its parent is gone (re-parented), when the poller's link is lost, or when the poller
says the device sent what cannot be true (DeviceProtocolError).
"""

from __future__ import annotations

import json
import logging
import os
import resource
import signal
import sys
import time
from pathlib import Path
from typing import Any

import zmq
from fluidsense.common.errors import ConfigError

from ..child import exit_now
from . import realtime, wire
from .poller import load_poller
from .slots import Block, SlotLoop, SpinClock

log = logging.getLogger("fluidsense.drivers.sampler.process")

START_LEAD_NS = 10_000_000  # slot 0 is this far after the hello: no late first slot
HOUSEKEEPING_S = 0.01  # control socket, parent and heartbeat are checked this often
FINAL_SEND_TIMEOUT_MS = 1000

_terminate = False


def _on_sigterm(signum: int, frame: Any) -> None:
    global _terminate
    _terminate = True


class Sender:
    """PUSHes messages without ever blocking the loop. When the daemon does not drain
    (its queue and ours are full), a block is dropped: its samples are counted as
    ``dropped`` and its slot counts travel with the next block that gets through, so
    the daemon's accounting stays complete."""

    def __init__(self, sock: zmq.Socket, heartbeat_ns: int) -> None:
        self.sock = sock
        self.heartbeat_ns = heartbeat_ns
        self.last_sent_ns = time.monotonic_ns()
        self.dropped_blocks = 0
        self.dropped_samples = 0
        self._carry: dict[str, int] | None = None

    def send(self, kind: str, fields: dict[str, Any] | None = None, arrays: tuple = ()) -> bool:
        try:
            self.sock.send_multipart(wire.encode(kind, fields, arrays), flags=zmq.NOBLOCK)
        except zmq.Again:
            return False
        self.last_sent_ns = time.monotonic_ns()
        return True

    def block(self, b: Block) -> None:
        c = b.counts
        carry = self._carry or {"slot_begin": b.slot_begin, "missed": 0, "failed": 0, "dropped": 0}
        fields = {"seq": b.seq, "n": len(b), "dtype": wire.DTYPE,
                  "slot_begin": carry["slot_begin"], "slot_end": b.slot_end,
                  "on_time": c.on_time, "late": c.late, "missed": c.missed + carry["missed"],
                  "failed": c.failed + carry["failed"], "dropped": carry["dropped"],
                  "read_max_s": b.read_max_s, "last_error": b.last_error,
                  "stalls": [[slot, ns / 1e9] for slot, ns in b.stalls], "slow": b.slow}
        if self.send("block", fields, (b.t_s, b.values, b.lateness_s)):
            if self._carry is not None:
                log.info("daemon draining again after %d dropped blocks", self.dropped_blocks)
            self._carry = None
            return
        if self._carry is None:
            log.warning("daemon is not draining: dropping blocks (their slots are reported as dropped)")
        self.dropped_blocks += 1
        self.dropped_samples += len(b)
        carry.update(missed=fields["missed"], failed=fields["failed"], dropped=carry["dropped"] + len(b))
        self._carry = carry

    def heartbeat_if_idle(self, slot: int) -> None:
        if time.monotonic_ns() - self.last_sent_ns >= self.heartbeat_ns:
            self.send("heartbeat", {"slot": slot})

    def final(self, kind: str, fields: dict[str, Any]) -> None:
        """The last message: worth waiting a little for the queue to make room."""
        self.sock.setsockopt(zmq.SNDTIMEO, FINAL_SEND_TIMEOUT_MS)
        try:
            self.sock.send_multipart(wire.encode(kind, fields))
        except zmq.Again:
            log.warning("could not send %s to the daemon (queue full)", kind)


class Housekeeper:
    """``should_stop`` of the loop: SIGTERM every slot; parent, control socket and
    heartbeat every ``every`` slots (cheap, but not free)."""

    def __init__(self, ctl: zmq.Socket, sender: Sender, parent_pid: int, every: int, loop: SlotLoop) -> None:
        self.ctl = ctl
        self.sender = sender
        self.parent_pid = parent_pid
        self.every = every
        self.loop = loop
        self.reason: str | None = None
        self._n = 0

    def __call__(self) -> bool:
        if _terminate:
            self.reason = "SIGTERM"
            return True
        self._n += 1
        if self._n < self.every:
            return False
        self._n = 0
        if os.getppid() != self.parent_pid:
            self.reason = "parent gone"
            return True
        if self.ctl.poll(0):
            header, _ = wire.decode(self.ctl.recv_multipart())
            if header["type"] == "stop":
                self.reason = "stop requested"
                return True
            log.warning("ignoring control message %r", header["type"])
        self.sender.heartbeat_if_idle(self.loop.next_slot)
        return False


def _cpu_snapshot() -> tuple[float, float, resource.struct_rusage]:
    return time.process_time(), time.thread_time(), resource.getrusage(resource.RUSAGE_SELF)


def _cpu_report(start: tuple[float, float, resource.struct_rusage], wall_s: float) -> dict[str, Any]:
    p0, t0, r0 = start
    p1, t1, r1 = _cpu_snapshot()
    return {"wall_s": wall_s, "process_cpu_s": p1 - p0, "loop_thread_cpu_s": t1 - t0,
            "voluntary_switches": r1.ru_nvcsw - r0.ru_nvcsw,
            "involuntary_switches": r1.ru_nivcsw - r0.ru_nivcsw,
            "minor_faults": r1.ru_minflt - r0.ru_minflt, "major_faults": r1.ru_majflt - r0.ru_majflt}


def run(args: dict[str, Any], poller: Any, sender: Sender, ctl: zmq.Socket,
        poller_threads: set[int] = frozenset()) -> int:
    rate_hz = float(args["rate_hz"])
    clock = SpinClock(spin_ns=int(args["spin_us"] * 1000))
    loop = SlotLoop(poller, clock, sender.block, rate_hz=rate_hz, block_size=int(args["block_size"]),
                    n_channels=len(args["channels"]), late_threshold_ns=int(args["late_threshold_us"] * 1000),
                    max_consecutive_failures=2, link_timeout_ns=int(args["link_timeout_s"] * 1e9))
    keeper = Housekeeper(ctl, sender, int(args["parent_pid"]), max(1, round(rate_hz * HOUSEKEEPING_S)), loop)
    report = realtime.apply(args["rt_priority"], args["cpu"], poller_threads=poller_threads)
    t0 = clock.now_ns() + START_LEAD_NS
    sender.send("hello", {"pid": os.getpid(), "t0_monotonic_ns": t0, "period_ns": loop.period_ns,
                          "realtime": report})
    cpu0 = _cpu_snapshot()
    try:
        result = loop.run(keeper, t0)
    except ConfigError as exc:
        sender.final("fatal", {"stage": "read", "error": str(exc)})
        log.error("%s", exc)
        return wire.EXIT_CONFIG
    end = clock.now_ns()
    fields = {"totals": result.totals.as_dict(), "slots": result.slots, "blocks": result.blocks,
              "t_end_s": (end - t0) / 1e9, "dropped_blocks": sender.dropped_blocks,
              "dropped_samples": sender.dropped_samples, "cpu": _cpu_report(cpu0, (end - t0) / 1e9)}
    if result.reason == "link_lost":
        sender.final("link_lost", {**fields, "error": result.detail})
        return wire.EXIT_LINK_LOST
    if result.reason == "implausible":
        sender.final("implausible", {**fields, "error": result.detail, "field": result.field})
        return wire.EXIT_IMPLAUSIBLE
    log.info("stopping (%s) after %d slots: %s", keeper.reason, result.slots, result.totals.as_dict())
    if keeper.reason != "parent gone":
        sender.final("stopped", {**fields, "reason": keeper.reason})
    return wire.EXIT_STOPPED


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = json.loads(argv[0])
    logging.basicConfig(level=int(args.get("log_level", logging.INFO)), stream=sys.stderr,
                        format="%(asctime)s sampler[%(process)d] %(levelname)s %(name)s: %(message)s")
    signal.signal(signal.SIGTERM, _on_sigterm)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    ctx = zmq.Context(io_threads=1)
    data = ctx.socket(zmq.PUSH)
    data.setsockopt(zmq.SNDHWM, 1000)
    data.setsockopt(zmq.LINGER, FINAL_SEND_TIMEOUT_MS)
    data.connect(args["data"])
    ctl = ctx.socket(zmq.PULL)
    ctl.setsockopt(zmq.LINGER, 0)
    ctl.connect(args["control"])
    sender = Sender(data, int(float(args["heartbeat_s"]) * 1e9))
    try:
        return _with_poller(args, sender, ctl)
    finally:
        orphaned = os.getppid() != int(args["parent_pid"])
        if orphaned:
            data.setsockopt(zmq.LINGER, 0)  # nobody left to read what is queued
        data.close()
        ctl.close()
        ctx.term()
        if orphaned:
            _remove_endpoints(args)


def _remove_endpoints(args: dict[str, Any]) -> None:
    """The ipc endpoints' files and their directory, which the daemon bound and removes when
    it stops: killed (SIGKILL, the OOM killer), it cannot, and a sampler that outlives it
    does (a sampler killed with it leaves them to the next daemon's start: common/rundirs.py).
    Only those two files and an emptied directory: nothing else is removed."""
    paths = [Path(args[name].removeprefix("ipc://")) for name in ("data", "control")
             if args[name].startswith("ipc://")]
    for path in paths:
        path.unlink(missing_ok=True)
    for folder in {path.parent for path in paths}:
        try:
            folder.rmdir()
        except OSError as exc:  # not empty, or already gone: not ours to force
            log.debug("left %s: %s", folder, exc)


def _with_poller(args: dict[str, Any], sender: Sender, ctl: zmq.Socket) -> int:
    spec = args["poller"]
    try:
        poller = load_poller(spec["factory"], spec.get("kwargs") or {})
    except ConfigError as exc:
        log.error("%s", exc)
        sender.final("fatal", {"stage": "construct", "error": str(exc)})
        return wire.EXIT_CONFIG
    before = realtime.threads()
    try:
        poller.open()
    except Exception as exc:  # noqa: BLE001 - reported to the daemon, which raises
        error = f"{type(exc).__name__}: {exc}"
        log.error("poller %s did not open: %s", spec["factory"], error)
        sender.final("fatal", {"stage": "open", "error": error})
        _close(poller)
        return wire.EXIT_OPEN
    try:
        return run(args, poller, sender, ctl, realtime.threads() - before)
    finally:
        _close(poller)


def _close(poller: Any) -> None:
    try:
        poller.close()
    except Exception as exc:  # noqa: BLE001 - closing must not hide why we stopped
        log.warning("poller close failed: %s: %s", type(exc).__name__, exc)


if __name__ == "__main__":
    exit_now(main())
