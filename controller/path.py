"""The sample path: one block from the driver to the published ``pressure`` event, hop by
hop, and the port each hop is wired through (service.py wires them; every part names what
it is handed, none gets a bare callable). docs/architecture.md "The sample path" says the
same in a table.

    drivers/base.py          SampleSource.read_block     the driver's block: 10 samples at 1 kHz
    sampling/loop.py         SampleLoop._read, ._run     the only reader: the block on to its
                                                         ``pipeline`` (BlockPipeline)
    service.py               Controller.on_block         every block, through these in order:
      sampling/clock.py        SampleClock.advance         now = the newest sample's time
                                                           (SampleTime, to every other part)
      cycles/runner.py         CycleRunner.trace           the running cycle keeps the samples
      safety/supervisor.py     Supervisor.check            limits, NaN, rail, stuck, leak: a Fault
      safety/latch.py          SafetyLatch.trip            latched (Faults): vent, confirm, publish
      cycles/runner.py         CycleRunner.on_block        the sequencer's actions (Events)
      safety/outputs.py        OutputWatch.on_block        valve read-back, the box watchdog's kick
      telemetry/fanout.py      Telemetry.on_block          the block into the pressure batch;
                               Telemetry.flush_pressure    a full batch (Stream: rate, clock
                                                           origin) is the ``pressure`` event:
      telemetry/publisher.py   Publisher.send              (EventPublisher) encoded, pushed to
      telemetry/outlet.py      Outlet.run                  the outlet process, which publishes it
      telemetry/fanout.py      Telemetry.on_block          then every sink (recording, live view)
      requests/grip.py         GripHandler.on_block        the block watchers (BlockWatcher): a
                                                           grip's contact, slip, timeout, max hold
      telemetry/fanout.py      Telemetry.heartbeat         when due
      safety/latch.py          SafetyLatch.trip_deferred   a fault found off the path (Faults)

Events other than ``pressure`` (a cycle's ``state`` and ``cycle``, a ``fault``, the
gripper's) leave the same way: ``Events.emit`` (Telemetry.emit) -> ``EventPublisher.send``,
and to every sink.
"""

from __future__ import annotations

from typing import Any, Protocol

from fluidsense.common.faults import Fault, FaultKind
from fluidsense.common.samples import SampleBlock


class SampleTime(Protocol):
    """Sample time, as the path's parts read it (sampling/clock.py SampleClock)."""

    @property
    def now(self) -> float:
        """The newest sample's timestamp (s): the controller's "now", never the wall clock."""
        ...


class BlockPipeline(Protocol):
    """What the sample loop hands on (service.py Controller): each block it reads, and a
    read that failed. The loop knows nothing else of the controller."""

    async def set_up(self) -> None:
        """Set the devices up for sampling; the loop connects through this (retrying, in
        the daemon, while the devices are not there)."""
        ...

    async def on_block(self, block: SampleBlock) -> None:
        """One block through every hop, in the order above."""
        ...

    async def on_read_failure(self, fault: Fault) -> None:
        """No block: latch ``fault``; whoever waits on samples is told none will come."""
        ...

    @property
    def wants_samples(self) -> bool:
        """Something waits on samples; in virtual time the loop parks otherwise."""
        ...


class Stream(Protocol):
    """What a published pressure batch says of the samples' source (drivers/base.py
    SampleSource), asked at each batch: a replayed recording knows its rate only once open."""

    @property
    def rate_hz(self) -> float:
        """Samples per second."""
        ...

    @property
    def clock_origin_s(self) -> float | None:
        """``time.monotonic()`` at sample time 0 (real time); None in virtual time."""
        ...


class EventPublisher(Protocol):
    """Where published events leave the controller (telemetry/publisher.py Publisher; its
    NullPublisher stand-in for a job that publishes nothing)."""

    dropped: int
    """Messages that never reached the outlet process (it fell behind, or died)."""

    def send(self, topic: str, t_s: float, payload: dict[str, Any]) -> None:
        """Publish ``payload`` on ``topic`` at sample time ``t_s``; never blocks."""
        ...

    @property
    def stats(self) -> dict[str, int]:
        """Its counts, for ``status``."""
        ...


class Events(Protocol):
    """Events from the path's parts out to the publisher and the sinks
    (telemetry/fanout.py Telemetry)."""

    def emit(self, topic: str, payload: dict[str, Any]) -> None:
        """Publish an event and hand it to every sink."""
        ...

    def record(self, topic: str, payload: dict[str, Any]) -> None:
        """Hand an event to the sinks only (what a replay needs: a cycle's start, each command)."""
        ...


class Faults(Protocol):
    """The safety latch, as the path's parts use it (safety/latch.py SafetyLatch)."""

    @property
    def fault(self) -> Fault | None:
        """The latched fault, if any."""
        ...

    async def trip(self, fault: Fault, now: float) -> None:
        """Latch ``fault`` now: stop the sequence, vent, confirm, publish."""
        ...

    def defer(self, detail: str, kind: FaultKind, now: float) -> None:
        """A fault found off the loop's flow: latched after the block being handled."""
        ...


class BlockWatcher(Protocol):
    """Follows the running cycle block by block, beside the telemetry (requests/grip.py
    GripHandler: a grip's contact, slip, timeout, max hold). Called from the sample loop
    after the block's telemetry: it must return quickly, and what it raises is a bug
    (dropped, and an internal fault)."""

    def on_block(self, block: SampleBlock) -> None:
        """One block of the samples, as the loop handled it."""
        ...
