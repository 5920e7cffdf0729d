"""Sampling polled sources in a dedicated process (design.md section 3).

A poller (Modbus analog input, RTDE receive, a synthetic signal) is read on a fixed grid
of slots by a separate process that sleeps to just before each deadline, spins to it,
reads and timestamps the sample with when it was really read. Every slot is accounted
for: on time, late (its lateness recorded), missed (the process woke after the next
slot's deadline), or failed (the read raised). Blocks go to the daemon over ZeroMQ
PUSH/ipc. ``SampledSource`` is the daemon side.
"""

from .config import PollerSpec, SamplerConfig
from .loop import Block, Clock, SlotLoop

__all__ = ["Block", "Clock", "PollerSpec", "SamplerConfig", "SlotLoop"]
