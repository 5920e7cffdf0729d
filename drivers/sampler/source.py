"""The daemon side of the sampler: a ``SampleSource`` fed by the sampler process."""

from __future__ import annotations

import asyncio
import json
import logging
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import zmq
import zmq.asyncio

from ..base import SampleBlock, SampleSource
from ..errors import LinkLostError
from .config import PollerSpec, SamplerConfig

log = logging.getLogger(__name__)


class SampledSource(SampleSource):
    """Samples from a poller read in a separate process (design.md section 3).

    Timestamps are the times the sampler really read each sample (seconds since the
    sampler started, its monotonic clock); missed and late slots come in each block.
    A dead or silent sampler, or one that reports its link lost, makes ``read_block``
    raise ``LinkLostError``.
    """

    virtual = False

    def __init__(self, name: str, cfg: SamplerConfig, poller: PollerSpec, channels: tuple[str, ...]):
        super().__init__(name)
        self.cfg = cfg
        self.poller = poller
        self.channels = tuple(channels)
        self.rate_hz = cfg.rate_hz
        self._proc: subprocess.Popen | None = None
        self._sock = None
        self._dir: tempfile.TemporaryDirectory | None = None
        self._seq = 0
        self.totals = {"on_time": 0, "late": 0, "missed": 0, "failed": 0}

    async def _setup(self) -> None:
        self._dir = tempfile.TemporaryDirectory(prefix="fluidsense-sampler-")
        endpoint = f"ipc://{Path(self._dir.name) / 'blocks'}"
        self._sock = zmq.asyncio.Context.instance().socket(zmq.PULL)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.bind(endpoint)
        args = json.dumps({"sampler": self.cfg.model_dump(), "poller": self.poller.model_dump(), "endpoint": endpoint})
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self._proc = subprocess.Popen([sys.executable, "-m", "drivers.sampler.process", args], env=env,
                                      stdin=subprocess.DEVNULL)
        log.info("sampler process %d started for %s", self._proc.pid, self.poller.target)
        # the first block proves the poller opened and the link works
        self._first = await self._receive(self.cfg.start_timeout_s)

    async def _receive(self, timeout_s: float) -> SampleBlock:
        try:
            frames = await asyncio.wait_for(self._sock.recv_multipart(), timeout_s)
        except asyncio.TimeoutError:
            code = self._proc.poll() if self._proc is not None else None
            why = f"exited with code {code}" if code is not None else f"silent for {timeout_s} s"
            raise LinkLostError(f"sampler for {self.poller.target} {why}") from None
        header = json.loads(frames[0])
        n, ch = header["n"], len(header["channels"])
        t_ns = np.frombuffer(frames[1], dtype="<i8")
        values = np.frombuffer(frames[2], dtype="<f8").reshape(n, ch)
        late_ns = np.frombuffer(frames[3], dtype="<i8")
        for key in self.totals:
            self.totals[key] += header[key]
        if header["link_lost"]:
            raise LinkLostError(f"sampler for {self.poller.target}: {header['link_lost']}")
        self._seq += 1
        return SampleBlock(self._seq, (t_ns - header["t0_ns"]) / 1e9, values.copy(), self.channels,
                           missed=header["missed"] + header["failed"], late=header["late"],
                           lateness_s=late_ns / 1e9)

    async def _read_block(self) -> SampleBlock:
        if getattr(self, "_first", None) is not None:
            block, self._first = self._first, None
            return block
        return await self._receive(self.cfg.silence_timeout_s)

    async def _stop(self) -> None:
        if self._proc is not None and self._proc.poll() is None:
            self._proc.terminate()
            try:
                await asyncio.get_running_loop().run_in_executor(None, self._proc.wait, 5.0)
            except subprocess.TimeoutExpired:
                self._proc.kill()
        if self._sock is not None:
            self._sock.close()
        if self._dir is not None:
            self._dir.cleanup()
