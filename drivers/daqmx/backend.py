"""Build the NI-DAQmx backend: one hardware-timed analog input task read in blocks, one
static digital output task for the valves, one static analog output task for the
regulator (docs/drivers.md).

Sample time is the device's sample clock: sample k is at k / rate_hz, exactly, because
the input buffer never drops a sample silently (DAQmx's "do not overwrite unread
samples": a buffer the loop lets fill stops the acquisition with an error, and that
error is a driver fault here). The host clock only aligns sample time with other
processes (``clock_origin_s``). Every DAQmx call that can wait runs on a thread of its
own, never in the event loop: the read waits for a block by design, and a USB device's
on-demand write takes a round trip.

The tasks come from ``task_factory`` (``nidaqmx.Task`` on a real machine) and the
device's watchdog task from ``watchdog_factory`` (``nidaqmx.system.WatchdogTask``,
watchdog.py): the tests put stand-ins there, because NI's driver library cannot run
where they run.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from fluidsense.common.errors import (
    ConfigError,
    DeviceProtocolError,
    LinkLostError,
)
from fluidsense.common.hardware import Hardware, RegulatedCircuit, TankCircuit
from fluidsense.common.samples import SampleBlock

from ..backend import Backend
from ..base import Regulator, SampleSource, ValveBank
from .blocks import block_rows, check_rate
from .calls import (
    BufferOverflowError,
    TaskThread,
    close_task,
    nidaqmx_package,
    translate,
)
from .config import DaqRegulatorWiring, NiDaqDriverConfig
from .watchdog import DaqWatchdog

log = logging.getLogger(__name__)

TaskFactory = Callable[[str], Any]


class DaqSource(SampleSource):
    def __init__(self, cfg: NiDaqDriverConfig, hw: Hardware, task_factory: TaskFactory):
        super().__init__(f"nidaqmx {cfg.device}")
        self.cfg, self.rate_hz, self.channels = cfg, float(cfg.rate_hz), hw.channels
        self._factory = task_factory
        affine = [cfg.wiring.sensors[c].transfer.affine() for c in self.channels]
        self._gain = np.array([g for g, _ in affine])
        self._offset = np.array([o for _, o in affine])
        self.buffer = int(round(cfg.buffer_s * cfg.rate_hz))
        self._task: Any = None
        self._worker = TaskThread("daqmx-ai")
        self._k = 0  # sample time of the next sample, in samples
        self._k_start = 0  # the current acquisition's first sample
        self._started_at = 0.0  # host time the current acquisition started
        self._origin: float | None = None
        self._seq = 0
        self._restart = False
        self._missed_pending = 0  # slots between two acquisitions, reported with the next block
        self.overflows = 0

    @property
    def clock_origin_s(self) -> float | None:
        return self._origin

    async def _setup(self) -> None:
        await self._worker.run(self._start_task)
        self._origin = self._started_at = time.monotonic()

    def _start_task(self) -> None:
        from nidaqmx.constants import (  # noqa: PLC0415
            AcquisitionType,
            OverwriteMode,
            TerminalConfiguration,
        )

        terminals = {"default": TerminalConfiguration.DEFAULT, "rse": TerminalConfiguration.RSE,
                     "nrse": TerminalConfiguration.NRSE, "differential": TerminalConfiguration.DIFF,
                     "pseudo_differential": TerminalConfiguration.PSEUDO_DIFF}
        task = self._factory(f"fluidsense-ai-{self.cfg.device}")
        try:
            for name in self.channels:
                s = self.cfg.wiring.sensors[name]
                lo, hi = s.limits()
                add = task.ai_channels.add_ai_voltage_chan if s.transfer.domain == "voltage" \
                    else task.ai_channels.add_ai_current_chan
                add(self.cfg.physical("ai", s.ai), name_to_assign_to_channel=name,
                    terminal_config=terminals[s.terminal], min_val=lo, max_val=hi)
            task.timing.cfg_samp_clk_timing(self.rate_hz, source=self.cfg.clock_source,
                                            sample_mode=AcquisitionType.CONTINUOUS, samps_per_chan=self.buffer)
            task.in_stream.input_buf_size = self.buffer
            # an unread sample is never overwritten: a full buffer is an error we see
            task.in_stream.over_write = OverwriteMode.DO_NOT_OVERWRITE_UNREAD_SAMPLES
            task.start()
        except Exception as exc:
            task.close()
            raise translate(exc, self.name) from exc
        self._task = task

    async def _stop(self) -> None:
        task, self._task = self._task, None
        if task is not None:
            await self._worker.run(close_task, task)
        self._worker.close()

    def _read(self) -> tuple[np.ndarray, float]:
        try:
            data = self._task.read(number_of_samples_per_channel=self.cfg.block_size,
                                   timeout=self.cfg.read_timeout_s)
        except Exception as exc:
            raise translate(exc, self.name) from exc
        arrival = time.monotonic()
        # one channel reads as a flat list, several as one list per channel (checked: blocks.py)
        return block_rows(data, self.channels, self.cfg.block_size), arrival

    async def _read_block(self) -> SampleBlock:
        if self._restart:
            await self._restart_task()
        try:
            signal, arrival = await self._worker.run(self._read)
            check_rate(self._k + len(signal) - self._k_start, self.rate_hz, arrival - self._started_at)
        except (BufferOverflowError, LinkLostError, DeviceProtocolError) as exc:
            # a new acquisition at the next read: after an overflow, a lost device, or a
            # block that cannot be true (nothing more this acquisition says is trusted)
            self.overflows += isinstance(exc, BufferOverflowError)
            self._restart = True
            raise
        n = len(signal)
        k = self._k + np.arange(n)
        self._k += n
        t = k / self.rate_hz
        # the least delayed block bounds the origin best (a block arrives after its last sample)
        self._origin = min(self._origin, arrival - t[-1])
        missed, self._missed_pending = self._missed_pending, 0
        self._seq += 1
        return SampleBlock(self._seq, t, (signal - self._offset) / self._gain, self.channels, missed=missed)

    async def _restart_task(self) -> None:
        """A new acquisition after an overflow or a lost device. Its first sample comes at
        the host time it starts: the slots in between are reported missed."""
        old, self._task = self._task, None
        if old is not None:
            await self._worker.run(close_task, old)
        await self._worker.run(self._start_task)
        self._started_at = time.monotonic()
        self._restart = False
        k = max(self._k, int(np.ceil((self._started_at - self._origin) * self.rate_hz)))
        self._missed_pending = k - self._k
        self._k = self._k_start = k
        log.warning("%s: acquisition restarted at sample %d (%d slots missed)", self.name, k, self._missed_pending)


class DaqValves(ValveBank):
    def __init__(self, cfg: NiDaqDriverConfig, safe: dict[str, bool], task_factory: TaskFactory):
        super().__init__(f"nidaqmx {cfg.device} lines", safe)
        self.cfg, self._factory = cfg, task_factory
        self.wiring = {v: cfg.wiring.valves[v] for v in self.names}
        self.reports_outputs = cfg.do_read_back
        self._levels = {v: w.level(safe[v]) for v, w in self.wiring.items()}
        self._task: Any = None
        self._worker = TaskThread("daqmx-do")

    async def _setup(self) -> None:
        await self._worker.run(self._open)

    def _open(self) -> None:
        from nidaqmx.constants import LineGrouping  # noqa: PLC0415

        task = self._factory(f"fluidsense-do-{self.cfg.device}")
        try:
            for valve, w in self.wiring.items():
                task.do_channels.add_do_chan(self.cfg.physical("line", w.line, w.port), name_to_assign_to_lines=valve,
                                             line_grouping=LineGrouping.CHAN_PER_LINE)
            self._task = task
            self._write_levels()  # the safe positions before anything else
        except Exception as exc:
            task.close()
            self._task = None
            raise translate(exc, self.name) from exc

    def _write_levels(self) -> None:
        levels = list(self._levels.values())
        self._task.write(levels if len(levels) > 1 else levels[0])

    async def _set(self, valve: str, open: bool, t: float) -> None:
        self._levels[valve] = self.wiring[valve].level(open)
        try:
            await self._worker.run(self._write_levels)
        except Exception as exc:
            raise translate(exc, self.name) from exc

    async def _read_positions(self) -> dict[str, bool] | None:
        if not self.cfg.do_read_back:
            return None
        try:
            got = await self._worker.run(self._task.read)
        except Exception as exc:
            raise translate(exc, self.name) from exc
        levels = got if isinstance(got, list) else [got]
        return {v: bool(level) == w.open_when_energised for (v, w), level in zip(self.wiring.items(), levels)}

    async def _stop(self) -> None:
        if self._task is not None:
            await self._worker.run(self._task.close)  # the lines keep their last (safe) level
            self._task = None
        self._worker.close()


class DaqRegulator(Regulator):
    def __init__(self, cfg: NiDaqDriverConfig, wiring: DaqRegulatorWiring, task_factory: TaskFactory):
        super().__init__(f"nidaqmx {cfg.device} ao{wiring.analog_output}")
        self.cfg, self.wiring, self._factory = cfg, wiring, task_factory
        self._task: Any = None
        self._worker = TaskThread("daqmx-ao")

    async def _setup(self) -> None:
        await self._worker.run(self._open)

    def _open(self) -> None:
        w = self.wiring
        task = self._factory(f"fluidsense-ao-{self.cfg.device}")
        lo, hi = sorted(w.signal)
        scale = 1.0 if w.input == "voltage" else 1e-3
        add = task.ao_channels.add_ao_voltage_chan if w.input == "voltage" else task.ao_channels.add_ao_current_chan
        try:
            add(self.cfg.physical("ao", w.analog_output), name_to_assign_to_channel="regulator",
                min_val=lo * scale, max_val=hi * scale)
            task.write(w.to_signal(0.0))
        except Exception as exc:
            task.close()
            raise translate(exc, self.name) from exc
        self._task = task

    async def _set_setpoint(self, pressure_pa: float, t: float) -> None:
        try:
            await self._worker.run(self._task.write, self.wiring.to_signal(pressure_pa))
        except Exception as exc:
            raise translate(exc, self.name) from exc

    async def _stop(self) -> None:
        if self._task is not None:
            await self._worker.run(self._task.close)
            self._task = None
        self._worker.close()


def build(cfg: NiDaqDriverConfig, hw: Hardware, task_factory: TaskFactory | None = None,
          read_only: bool = False, watchdog_factory: Callable[..., Any] | None = None) -> Backend:
    if read_only:  # set-up writes the valves' safe levels to the digital lines
        raise ConfigError("driver: the nidaqmx driver has no read-only mode (set-up writes the safe levels); "
                          "use fluidsense check --actuate")
    factory = task_factory or nidaqmx_package().Task
    valves = DaqValves(cfg, hw.circuit.safe_valves, factory)
    regulated = isinstance(hw.circuit, (TankCircuit, RegulatedCircuit)) and cfg.wiring.regulator is not None
    regulator = DaqRegulator(cfg, cfg.wiring.regulator, factory) if regulated else None
    watchdog = None
    if cfg.watchdog.enabled:  # set up after the valves and the regulator: their safe levels are written first
        if watchdog_factory is None:
            nidaqmx_package()
            from nidaqmx.system import WatchdogTask as watchdog_factory  # noqa: PLC0415, N813
        watchdog = DaqWatchdog(cfg, valves.wiring, hw.circuit.safe_valves, cfg.wiring.regulator if regulated else None,
                               watchdog_factory, TaskThread("daqmx-wdt"))
    return Backend(name="nidaqmx", source=DaqSource(cfg, hw, factory), valves=valves, regulator=regulator,
                   watchdog=watchdog)
