"""The simulated cell as an ordinary backend: the same device interfaces as real drivers.

Samples are "hardware timed": sample k is taken at exactly k / rate_hz seconds. In
virtual time a block is produced as soon as it is asked for; in real time the source
waits until the wall clock has reached the block's last sample, as a DAQ would.
"""

from __future__ import annotations

import asyncio
import logging
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np
from fluidsense.common.errors import DeviceTimeoutError, LinkLostError
from fluidsense.common.hardware import (
    FlowControlledCircuit,
    Hardware,
    RegulatedCircuit,
    TankCircuit,
)
from fluidsense.common.samples import SampleBlock
from fluidsense.simulator.cell import SimulatedCell

from ..backend import Backend
from ..base import FlowController, Regulator, SampleSource, SceneControl, ValveBank
from ..registry import SimDriverConfig
from .arm import SimArm

log = logging.getLogger(__name__)

class SimSource(SampleSource):
    def __init__(self, cell: SimulatedCell):
        super().__init__("sim-source")
        self.cell = cell
        self.channels = cell.channels
        self.rate_hz = cell.cfg.rate_hz
        self.virtual = cell.cfg.clock == "virtual"
        self._seq = 0
        self._wall_t0: float | None = None
        self._pacer: ThreadPoolExecutor | None = None

    @property
    def clock_origin_s(self) -> float | None:
        return None if self.virtual else self._wall_t0  # the event loop's clock is time.monotonic

    async def _setup(self) -> None:
        self._wall_t0 = asyncio.get_running_loop().time() - self.cell.t_next
        if not self.virtual:
            self._pacer = ThreadPoolExecutor(1, thread_name_prefix="sim-pacer")

    async def _stop(self) -> None:
        if self._pacer is not None:
            self._pacer.shutdown(wait=False)
            self._pacer = None

    async def _read_block(self) -> SampleBlock:
        self.cell._due_faults(self.cell.t_next)
        if self.cell.source_fault is not None:  # an injected failure: once, then it recovers
            kind, self.cell.source_fault = self.cell.source_fault, None
            if kind == "no_data":
                raise DeviceTimeoutError("simulated cell: no samples (injected)")
            raise LinkLostError("simulated cell: link lost (injected)")
        t, values = self.cell.next_block(self.cell.cfg.block_size)
        if not self.virtual:
            loop = asyncio.get_running_loop()
            delay = self._wall_t0 + float(t[-1]) - loop.time()
            if delay > 0:
                # asyncio's epoll timeouts round up to whole milliseconds (and float error
                # can add one more): blocks came 1.2 ms late at the median. A thread's
                # sleep (clock_nanosleep) hands them over within about 0.1 ms.
                await loop.run_in_executor(self._pacer, time.sleep, delay)
        else:
            await asyncio.sleep(0)  # let the rest of the daemon run between blocks
        self._seq += 1
        return SampleBlock(self._seq, t, values, self.channels)


class SimValves(ValveBank):
    reports_outputs = True

    def __init__(self, cell: SimulatedCell):
        super().__init__("sim-valves", cell.hw.circuit.safe_valves)
        self.cell = cell

    async def _set(self, valve: str, open: bool, t: float) -> None:
        self.cell.command_valve(valve, open, t)

    async def _read_positions(self) -> dict[str, bool]:
        return dict(self.cell.outputs)


class SimRegulator(Regulator):
    def __init__(self, cell: SimulatedCell):
        super().__init__("sim-regulator")
        self.cell = cell

    async def _set_setpoint(self, pressure_pa: float, t: float) -> None:
        self.cell.command_setpoint(pressure_pa, t)


class SimFlowController(FlowController):
    def __init__(self, cell: SimulatedCell):
        super().__init__("sim-mfc", cell.hw.circuit.max_flow)
        self.cell = cell

    async def _set_profile(self, times: np.ndarray, flows: np.ndarray, t: float) -> None:
        self.cell.command_flow_profile(times, flows, t)


class SimScene(SceneControl):
    def __init__(self, cell: SimulatedCell):
        super().__init__("sim-scene")
        self.cell = cell

    async def set_scene(self, scene, t: float) -> None:
        self.cell.set_scene(scene, t)

    async def set_world(self, world, t: float) -> None:
        self.cell.set_world(world, t)

    def truth(self) -> dict[str, Any]:
        return self.cell.truth()


@dataclass
class SimBackend(Backend):
    """The simulated cell's backend: the ordinary devices, and the cell itself for what
    only a simulation has (fault injection, the plant's true values, ground truth)."""

    sim: SimulatedCell | None = None


def build(cfg: SimDriverConfig, hw: Hardware, read_only: bool = False) -> SimBackend:
    """``read_only`` changes nothing: the simulated cell is built in its safe state and
    its set-up writes nothing."""
    cell = SimulatedCell(cfg, hw)
    c = hw.circuit
    regulator = SimRegulator(cell) if isinstance(c, (TankCircuit, RegulatedCircuit)) else None
    flow = SimFlowController(cell) if isinstance(c, FlowControlledCircuit) else None
    return SimBackend(name="sim", source=SimSource(cell), valves=SimValves(cell), regulator=regulator,
                      flow=flow, scene=SimScene(cell), arm=SimArm(cell), sim=cell)


__all__ = ["SimBackend", "build"]
