"""The sampler process: ``python -m drivers.sampler.process CONFIG_JSON``.

Applies what it may of the real-time settings (each refusal logged once, with the
reason), builds the poller, connects a PUSH socket to the daemon and runs the slot loop
until SIGTERM, a stop message, or its parent going away.

Wire format, per block: frame 0 a JSON header (seq, n, channels, t0_ns, on_time, late,
missed, failed, link_lost); frames 1-3 raw little-endian int64 read times (ns, the
process's monotonic clock), float64 values (n x channels, row-major) and int64 lateness
(ns). Never pickle.
"""

from __future__ import annotations

import ctypes
import gc
import json
import logging
import os
import signal
import sys
from typing import Any

import zmq

from .config import PollerSpec, SamplerConfig
from .loop import Block, RealClock, SlotLoop

log = logging.getLogger("fluidsense.sampler")

PR_SET_TIMERSLACK = 29


def apply_realtime(cfg: SamplerConfig) -> dict[str, Any]:
    """What could be applied: pinning, SCHED_FIFO, timer slack, gc. Never fails."""
    applied: dict[str, Any] = {}
    if cfg.cpu is not None:
        try:
            os.sched_setaffinity(0, {cfg.cpu})
            applied["cpu"] = cfg.cpu
        except OSError as exc:
            log.warning("sampler: could not pin to CPU %s: %s", cfg.cpu, exc.strerror or exc)
    if cfg.realtime_priority is not None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(cfg.realtime_priority))
            applied["sched_fifo"] = cfg.realtime_priority
        except (OSError, AttributeError) as exc:
            log.warning("sampler: SCHED_FIFO priority %s not permitted (%s): running SCHED_OTHER",
                        cfg.realtime_priority, getattr(exc, "strerror", None) or exc)
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(PR_SET_TIMERSLACK, 1, 0, 0, 0) == 0:
            applied["timer_slack_ns"] = 1
        else:
            log.warning("sampler: timer slack not set: %s", os.strerror(ctypes.get_errno()))
    except (OSError, AttributeError) as exc:
        log.warning("sampler: timer slack not available on this platform: %s", exc)
    gc.freeze()
    gc.disable()
    applied["gc"] = "frozen, disabled"
    return applied


class Sender:
    def __init__(self, endpoint: str, channels: tuple[str, ...], t0_ns: int):
        self.ctx = zmq.Context()
        self.sock = self.ctx.socket(zmq.PUSH)
        self.sock.setsockopt(zmq.LINGER, 1000)
        self.sock.setsockopt(zmq.SNDHWM, 10_000)
        self.sock.connect(endpoint)
        self.channels = channels
        self.t0_ns = t0_ns
        self.seq = 0
        self.parent = os.getppid()
        self.loop: SlotLoop | None = None

    def __call__(self, block: Block) -> None:
        self.seq += 1
        t, v, late = block.arrays(len(self.channels))
        header = {"seq": self.seq, "n": len(t), "channels": list(self.channels), "t0_ns": self.t0_ns,
                  "on_time": block.on_time, "late": block.late, "missed": block.missed, "failed": block.failed,
                  "link_lost": block.link_lost}
        self.sock.send_multipart([json.dumps(header).encode(), t.astype("<i8").tobytes(),
                                  v.astype("<f8").tobytes(), late.astype("<i8").tobytes()], copy=False)
        if os.getppid() != self.parent and self.loop is not None:  # orphaned: nobody reads us
            self.loop.stop = True

    def close(self) -> None:
        self.sock.close()
        self.ctx.term()


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s")
    args = json.loads((argv or sys.argv[1:])[0])
    cfg = SamplerConfig.model_validate(args["sampler"])
    poller = PollerSpec.model_validate(args["poller"]).build()
    applied = apply_realtime(cfg)
    poller.open()
    clock = RealClock(int(cfg.spin_us * 1000))
    sender = Sender(args["endpoint"], tuple(poller.channels), clock.now_ns())
    loop = SlotLoop(clock, cfg.period_ns, poller.read, sender, cfg.block_size, int(cfg.late_threshold_us * 1000),
                    cfg.max_consecutive_failures)
    sender.loop = loop

    def stop(*_: object) -> None:
        loop.stop = True

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    log.info("sampler: %s at %.0f Hz, blocks of %d, applied %s", poller.__class__.__name__, cfg.rate_hz,
             cfg.block_size, applied)
    try:
        loop.run()
    finally:
        poller.close()
        sender.close()
    return 0


if __name__ == "__main__":  # pragma: no cover - run as a process
    sys.exit(main())
