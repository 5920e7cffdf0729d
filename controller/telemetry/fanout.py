"""Telemetry: one fan-out of the controller's events to the publisher and the sinks (the
recording, a test's probe, a monitor).

Every event goes to both; two go to the sinks only, which a recording needs to replay a
cycle exactly: ``cycle_start`` and ``command``. Pressure samples are published in
batches: ``on_block`` -> ``_batch_pressure`` -> ``flush_pressure``, the ``pressure`` event
(controller/path.py: the sample path). Nothing here raises into the sample loop: a
publisher or sink that fails is deferred as an internal fault (``faults``, the safety
latch: latched after the block), a sink that reports a failure it knows (a full disk
stops a recording) is dropped and control goes on.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np
from fluidsense.common.errors import FluidsenseError
from fluidsense.common.faults import FaultKind
from fluidsense.common.samples import SampleBlock
from fluidsense.common.units import KPA, SLPM

from ..config import PublisherConfig
from ..path import EventPublisher, Faults, SampleTime, Stream

log = logging.getLogger(__name__)

_EDGE_SCALE = {"kPa": KPA, "SLPM": SLPM}


def edge_unit(channel: str) -> str:
    """Unit of a channel at the published edge: pressures in kPa, flows in SLPM."""
    return "SLPM" if channel.startswith("flow") else "kPa"


class Sink:
    """Something that keeps what the controller sees. Every method is called from the
    sample loop and must return quickly (a slow one queues its work elsewhere)."""

    def on_block(self, block: SampleBlock) -> None: ...

    def on_event(self, topic: str, t_s: float, payload: dict[str, Any]) -> None: ...

    def flush(self, t_s: float) -> None: ...

    def close(self) -> None: ...


class Telemetry:
    def __init__(self, publisher: EventPublisher, cfg: PublisherConfig, *, clock: SampleTime, stream: Stream,
                 faults: Faults):
        """``publisher``: where events leave; ``clock``: sample time, each event's stamp;
        ``stream``: the samples' source, its rate and clock origin asked at each batch;
        ``faults``: where a failing publisher or sink is deferred as an internal fault."""
        self.pub, self.cfg = publisher, cfg
        #: pressure batches are built: for any publisher but the null one (a test's stand-in
        #: need not say); ``python -m lab bench sim --batches`` turns it on to cost them
        self.batches = getattr(publisher, "publishes", True)
        self._clock, self._stream, self._faults = clock, stream, faults
        self.sinks: list[Sink] = []
        #: sinks dropped after a failure, for status: sink, state ("failed"), reason, t_s
        self.failed_sinks: list[dict[str, Any]] = []
        self._batch: list[SampleBlock] = []
        self._batch_start: float | None = None
        self._next_heartbeat = 0.0
        self._started = time.monotonic()

    # ------------------------------------------------------------------ events
    def emit(self, topic: str, payload: dict[str, Any]) -> None:
        """Publish an event and hand it to every sink."""
        try:
            self.pub.send(topic, self._clock.now, payload)
        except Exception as exc:  # noqa: BLE001
            log.exception("publishing %s failed", topic)
            self._fail(f"publishing {topic!r} failed: {type(exc).__name__}: {exc}")
        self.record(topic, payload)

    def record(self, topic: str, payload: dict[str, Any]) -> None:
        """Hand an event to the sinks only."""
        for sink in list(self.sinks):
            try:
                sink.on_event(topic, self._clock.now, payload)
            except Exception as exc:  # noqa: BLE001 - dropped, and maybe a fault
                self._drop(sink, exc)

    def on_block(self, block: SampleBlock) -> None:
        if self.batches:
            self._batch_pressure(block)
        for sink in list(self.sinks):
            try:
                sink.on_block(block)
            except Exception as exc:  # noqa: BLE001
                self._drop(sink, exc)

    def _drop(self, sink: Sink, exc: Exception) -> None:
        """A sink that reports a failure it knows (a full disk) is dropped and control goes
        on; it stays in status as failed, with the reason, and a ``log`` event (ERROR) tells
        the operator. Anything else it raises is a bug: the same, and a fault."""
        self.sinks.remove(sink)
        name = getattr(sink, "name", type(sink).__name__)
        known = isinstance(exc, FluidsenseError)
        reason = str(exc) if known else f"{type(exc).__name__}: {exc}"
        self.failed_sinks.append({"sink": name, "state": "failed", "reason": reason, "t_s": self._clock.now})
        if known:
            log.error("sink %s dropped: %s", name, exc)
        else:
            log.error("sink %s failed and was dropped: %s", name, exc, exc_info=exc)
        self.emit("log", {"level": "ERROR", "message": f"sink {name} failed and was dropped: {reason}",
                          "sink": name})
        if not known:
            self._fail(f"sink {name} failed: {reason}")

    def _fail(self, detail: str) -> None:
        """A bug here: an internal fault, latched after the block (nothing raises into the loop)."""
        self._faults.defer(detail, FaultKind.INTERNAL, self._clock.now)

    # ------------------------------------------------------------------ heartbeat
    def heartbeat_due(self) -> bool:
        return self._clock.now >= self._next_heartbeat

    def heartbeat(self, fields: dict[str, Any], proc_s) -> None:
        """``fields``: the controller's state; ``proc_s``: block handling times (s), cleared."""
        period = self.cfg.heartbeat_s
        self._next_heartbeat = (np.floor(self._clock.now / period) + 1) * period
        proc = np.array(proc_s) * 1e6 if proc_s else np.zeros(1)
        p50, p99 = np.percentile(proc, [50, 99]).tolist()
        self.emit("heartbeat", {**fields, "block_proc_us": {"p50": p50, "p99": p99, "max": float(proc.max())},
            "pub_dropped": self.pub.dropped, "uptime_s": time.monotonic() - self._started})
        proc_s.clear()

    # ------------------------------------------------------------------ pressure
    def _batch_pressure(self, block: SampleBlock) -> None:
        if self._batch_start is None:
            self._batch_start = float(block.t[0])
        self._batch.append(block)
        # n samples cover n sample periods: a batch as long as one block is one block.
        # Half a period of slack: a polled source stamps each read when it happens, and a
        # first sample a few ns later than the last one must not hold the batch for a
        # second block (measured: the oldest sample 20 ms old instead of 10 on Modbus)
        period = 1.0 / self._stream.rate_hz
        covered = self._clock.now + period - self._batch_start
        if covered + 0.5 * period >= self.cfg.pressure_batch_s:
            self.flush_pressure()

    def flush_pressure(self) -> None:
        if not self._batch:
            return
        t = np.concatenate([b.t for b in self._batch])
        channels = self._batch[0].channels
        v = np.vstack([b.values for b in self._batch]) / np.array([_EDGE_SCALE[edge_unit(c)] for c in channels])
        origin = self._stream.clock_origin_s
        self.pub.send("pressure", self._clock.now, {
            "t0_s": float(t[0]), "rate_hz": self._stream.rate_hz, "n": len(t),
            "clock_origin_s": origin, "sent_s": None if origin is None else time.monotonic(),
            "channels": list(channels), "units": [edge_unit(c) for c in channels],
            "times_s": t.tolist(), "values": np.round(v, 5).T.tolist()})
        self._batch, self._batch_start = [], None

    def close(self) -> None:
        """The last pressure batch out; every sink flushed and closed."""
        self.flush_pressure()
        for sink in self.sinks:
            try:
                sink.flush(self._clock.now)
                sink.close()
            except Exception as exc:  # noqa: BLE001 - closing the others matters more
                log.error("closing sink %s: %s", type(sink).__name__, exc)
