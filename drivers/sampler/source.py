"""The daemon's side of a polled source: spawns the sampler process and turns its
messages into SampleBlocks.

Blocks arrive over ZeroMQ PULL (zmq.asyncio) on an ipc endpoint in a private
temporary directory. A block's ``missed`` is every slot since the previous delivered
block that produced no sample here: missed and failed slots and samples dropped on
the way (``stats`` keeps them apart). ``read_block()`` raises LinkLostError when the
poller's link is lost, when the process exits or stops on its own, or when it stays
silent longer than ``silence_timeout_s`` (it sends heartbeats when it has no block);
it raises DeviceProtocolError once, naming the field, when the poller found the device
saying what cannot be true (the process has ended), and LinkLostError after it.
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import shutil
import signal
import subprocess
import sys
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np
import zmq
import zmq.asyncio
from fluidsense.common.errors import (
    ConfigError,
    DeviceProtocolError,
    DeviceTimeoutError,
    DriverError,
    LinkLostError,
)
from fluidsense.common.rundirs import private_dir
from fluidsense.common.samples import SampleBlock
from fluidsense.drivers.base import SampleSource

from . import wire
from .config import SamplerConfig

log = logging.getLogger(__name__)

#: how often a waiting read_block() checks that the process is still alive
LIVENESS_POLL_S = 0.05
DIR_PREFIX = "fluidsense-sampler-"  # the endpoints' folder: <temp>/DIR_PREFIX<pid>-XXXXXXXX (common/rundirs.py)
RCVHWM = 1000  # blocks; with the sampler's SNDHWM, about 20 s of 1 kHz data can queue


def _exit_text(code: int) -> str:
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


class SampledSource(SampleSource):
    """A polled source sampled in its own process (docs/architecture.md, decision 3)."""

    def __init__(self, cfg: SamplerConfig, name: str = "sampler") -> None:
        super().__init__(name)
        self.cfg = cfg
        self.rate_hz = cfg.rate_hz
        self.channels = tuple(cfg.channels)
        self.virtual = False
        #: what the process reported in its hello: pid, t0, the real-time settings
        self.hello: dict[str, Any] | None = None
        #: the process's last word (``stopped`` / ``link_lost`` / ``implausible`` / ``fatal``), once it came
        self.final: dict[str, Any] | None = None
        #: counts from every block received: on_time/late count delivered samples
        self.stats = {"on_time": 0, "late": 0, "missed": 0, "failed": 0, "dropped": 0, "slots": 0, "blocks": 0,
                      "stalls": 0, "stall_max_s": 0.0, "slow": 0}
        #: the latest stalls, (slot served after it, how late the loop woke in s): a
        #: stall is a wake-up after the next slot's deadline, which made slots missed
        self.stall_log: deque[tuple[int, float]] = deque(maxlen=10_000)
        self.proc: subprocess.Popen | None = None
        self._ctx: zmq.asyncio.Context | None = None
        self._pull: zmq.asyncio.Socket | None = None
        self._ctl: zmq.asyncio.Socket | None = None
        self._dir: Path | None = None
        self._seq = 0
        self._pending_missed = 0
        self._lost: LinkLostError | None = None

    @property
    def pid(self) -> int | None:
        return self.proc.pid if self.proc is not None else None

    @property
    def clock_origin_s(self) -> float | None:
        return self.t0_monotonic_s

    @property
    def t0_monotonic_s(self) -> float | None:
        """CLOCK_MONOTONIC time of slot 0: add it to a block's ``t`` for an absolute time."""
        return self.hello["t0_monotonic_ns"] / 1e9 if self.hello else None

    # ----------------------------------------------------------------- set-up
    async def _setup(self) -> None:
        self._lost = None
        self._dir = private_dir(DIR_PREFIX)
        self._ctx = zmq.asyncio.Context()
        try:
            self._pull = self._ctx.socket(zmq.PULL)
            self._pull.setsockopt(zmq.RCVHWM, RCVHWM)
            self._pull.setsockopt(zmq.LINGER, 0)
            self._pull.bind(f"ipc://{self._dir}/data")
            self._ctl = self._ctx.socket(zmq.PUSH)
            self._ctl.setsockopt(zmq.LINGER, 0)
            self._ctl.bind(f"ipc://{self._dir}/control")
            self.proc = self._spawn()
            await self._await_hello()
        except BaseException:
            await self._shutdown()
            raise

    def _spawn(self) -> subprocess.Popen:
        args = {**self.cfg.model_dump(mode="json"), "data": f"ipc://{self._dir}/data",
                "control": f"ipc://{self._dir}/control", "parent_pid": os.getpid(),
                "heartbeat_s": self.cfg.silence_timeout_s / 4, "log_level": log.getEffectiveLevel()}
        # stdout unused, stderr shared for its log
        proc = subprocess.Popen([sys.executable, "-m", "fluidsense.drivers.sampler.process", json.dumps(args)],
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, close_fds=True)
        log.info("sampler process %d spawned: %s at %g Hz, blocks of %d", proc.pid,
                 self.cfg.poller.factory, self.cfg.rate_hz, self.cfg.block_size)
        return proc

    async def _await_hello(self) -> None:
        try:
            header, _ = await self._next_message(self.cfg.start_timeout_s, starting=True)
        except LinkLostError as exc:
            if isinstance(exc.__cause__, TimeoutError):
                raise DeviceTimeoutError(f"sampler process {self.pid} did not start within "
                                         f"{self.cfg.start_timeout_s:g} s") from exc.__cause__
            raise
        if header["type"] == "fatal":
            self.final = header
            if header.get("stage") == "construct":
                raise ConfigError(f"sampler poller: {header['error']}")
            raise LinkLostError(f"sampler poller did not open: {header['error']}") from DriverError(header["error"])
        if header["type"] != "hello":
            raise DriverError(f"sampler process sent {header['type']!r} before its hello")
        self.hello = header
        rt = header["realtime"]
        log.info("sampler process %d running: %s", self.pid,
                 "; ".join(f"{k}: {'yes' if v['applied'] else 'no'} ({v['detail']})" for k, v in rt.items()))

    # ----------------------------------------------------------------- reading
    async def _read_block(self) -> SampleBlock:
        while True:
            if self._lost is not None:
                raise LinkLostError(str(self._lost)) from self._lost.__cause__
            header, frames = await self._next_message(self.cfg.silence_timeout_s)
            kind = header["type"]
            if kind == "block":
                block = self._to_block(header, frames)
                if block is not None:
                    return block
            elif kind in ("link_lost", "implausible", "fatal", "stopped"):
                self.final = header
                self._lose_from_message(header)
            elif kind != "heartbeat":
                log.warning("ignoring sampler message %r", kind)

    def _lose_from_message(self, header: dict[str, Any]) -> None:
        kind = header["type"]
        if kind == "link_lost":
            self._lose(f"sampler: poller link lost ({header['error']})", DriverError(header["error"]))
        elif kind == "implausible":
            # one fault that names the field; every later read says the link is lost
            lie = DeviceProtocolError(header["error"], header.get("field", ""))
            self._lost = LinkLostError(f"sampler: the device said what cannot be true ({lie.field}); reconnecting")
            self._lost.__cause__ = lie
            log.error("sampler: %s", lie)
            raise lie
        elif kind == "fatal":
            cause = ConfigError(header["error"]) if header.get("stage") in ("construct", "read") \
                else DriverError(header["error"])
            self._lose(f"sampler failed: {header['error']}", cause)
        else:
            self._lose(f"sampler stopped on its own ({header.get('reason')})", None)

    def _lose(self, message: str, cause: BaseException | None) -> None:
        err = LinkLostError(message)
        err.__cause__ = cause
        self._lost = err
        log.error("%s", message)
        raise err from cause

    async def _next_message(self, timeout_s: float, starting: bool = False) -> tuple[dict, list[bytes]]:
        """The next message; raises LinkLostError when the process has exited (after
        everything it sent has been read) or nothing came for ``timeout_s``."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while True:
            wait_s = min(LIVENESS_POLL_S, max(0.0, deadline - loop.time()))
            if await self._pull.poll(timeout=int(wait_s * 1000)):
                frames = await self._pull.recv_multipart()
                return wire.decode(frames)
            code = self.proc.poll()
            if code is not None and not self._readable():
                when = " while starting" if starting else ""
                self._lose(f"sampler process {self.proc.pid} exited{when} ({_exit_text(code)})",
                           ChildProcessError(f"sampler process {self.proc.pid}: {_exit_text(code)}"))
            if loop.time() >= deadline:
                self._lose(f"sampler process {self.proc.pid} silent for {timeout_s:g} s",
                           TimeoutError(f"no message from the sampler within {timeout_s:g} s"))

    def _readable(self) -> bool:
        # the socket's own flags: an asyncio socket's poll() returns a future
        return bool(self._pull.getsockopt(zmq.EVENTS) & zmq.POLLIN)

    def _to_block(self, h: dict[str, Any], frames: list[bytes]) -> SampleBlock | None:
        n = int(h["n"])
        for key in ("on_time", "late", "missed", "failed", "dropped"):
            self.stats[key] += int(h[key])
        self.stats["slots"] += int(h["slot_end"]) - int(h["slot_begin"])
        self.stats["blocks"] += 1
        self.stats["slow"] += int(h.get("slow", 0))
        for slot, stall_s in h.get("stalls", ()):
            self.stats["stalls"] += 1
            self.stats["stall_max_s"] = max(self.stats["stall_max_s"], stall_s)
            self.stall_log.append((slot, stall_s))
        missed = int(h["missed"]) + int(h["failed"]) + int(h["dropped"])
        if h.get("last_error"):
            log.debug("sampler: %d failed reads, last: %s", h["failed"], h["last_error"])
        if n == 0:  # only counts: they go with the next block that has samples
            self._pending_missed += missed
            return None
        dtype = np.dtype(h["dtype"])
        t = np.frombuffer(frames[0], dtype=dtype).astype(np.float64)
        values = np.frombuffer(frames[1], dtype=dtype).astype(np.float64).reshape(n, len(self.channels))
        lateness = np.frombuffer(frames[2], dtype=dtype).astype(np.float64)
        self._seq += 1
        missed += self._pending_missed
        self._pending_missed = 0
        return SampleBlock(self._seq, t, values, self.channels, missed=missed, late=int(h["late"]),
                           lateness_s=lateness)

    # ----------------------------------------------------------------- stopping
    async def _stop(self) -> None:
        await self._shutdown()

    async def _shutdown(self) -> None:
        try:
            if self.proc is not None:
                await self._stop_process()
        finally:
            for sock in (self._pull, self._ctl):
                if sock is not None:
                    sock.close(linger=0)
            if self._ctx is not None:
                self._ctx.term()
            if self._dir is not None:
                shutil.rmtree(self._dir, ignore_errors=True)
            self._pull = self._ctl = self._ctx = None
            self._dir = None

    async def _stop_process(self) -> None:
        proc = self.proc
        if proc.poll() is None and self._ctl is not None:
            try:
                await self._ctl.send_multipart(wire.encode("stop"), flags=zmq.NOBLOCK)
            except zmq.ZMQError as exc:  # it is on its way out and no longer listens
                log.debug("could not send stop to the sampler: %s", exc)
            await self._drain_until_final()
        if not await self._wait_exit(self.cfg.stop_timeout_s):
            log.warning("sampler process %d did not stop within %g s: SIGTERM", proc.pid, self.cfg.stop_timeout_s)
            proc.terminate()
            if not await self._wait_exit(self.cfg.stop_timeout_s):
                log.warning("sampler process %d ignored SIGTERM: SIGKILL", proc.pid)
                proc.kill()
                await self._wait_exit(None)
        log.info("sampler process %d ended (%s)", proc.pid, _exit_text(proc.returncode))

    async def _wait_exit(self, timeout_s: float | None) -> bool:
        try:
            await asyncio.to_thread(self.proc.wait, timeout_s)
        except subprocess.TimeoutExpired:
            return False
        return True

    async def _drain_until_final(self) -> None:
        """Read what is still queued (its counts go into ``stats``) until the process's
        last word, so that the totals it reports can be checked against ``stats``."""
        if self.final is not None or self._pull is None:
            return
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.cfg.stop_timeout_s
        while loop.time() < deadline:
            if not await self._pull.poll(timeout=int(LIVENESS_POLL_S * 1000)):
                if self.proc.poll() is not None and not self._readable():
                    return
                continue
            header, frames = wire.decode(await self._pull.recv_multipart())
            if header["type"] == "block":
                self._to_block(header, frames)
            elif header["type"] in ("stopped", "link_lost", "implausible", "fatal"):
                self.final = header
                return
