"""The DAQ's own watchdog timer (``nidaqmx.system.WatchdogTask``): the device sets the
valve lines (and, where it can, the regulator's analog output) to their safe levels by
itself when the service stops resetting the timer for ``driver.watchdog.timeout_s``: the
PC, the daemon or its sample loop died or hung. The controller's sample loop resets it
(``kick``) four times per timeout while it makes progress, as it heartbeats every box.

Which devices have one (docs/drivers.md): X Series boards (63xx) on their digital lines,
CompactDAQ Ethernet chassis (cDAQ-9185/9189) on analog, digital and counter outputs, and
others whose manual has a "Watchdog Timer" section. A device without one refuses the task
(WATCHDOG_TIMER_NOT_SUPPORTED): set-up fails with a config error unless the config says
``watchdog: {enabled: false}``, and then the lines keep their last level when the PC dies.
"""

from __future__ import annotations

import logging
from typing import Any

from fluidsense.common.errors import ConfigError, DriverError

from ..base import BoxWatchdog
from .calls import close_task, translate
from .config import DaqRegulatorWiring, DaqValveWiring, NiDaqDriverConfig

log = logging.getLogger(__name__)


class DaqWatchdog(BoxWatchdog):
    def __init__(self, cfg: NiDaqDriverConfig, valves: dict[str, DaqValveWiring], safe: dict[str, bool],
                 regulator: DaqRegulatorWiring | None, factory: Any, worker: Any):
        super().__init__(f"nidaqmx {cfg.device} watchdog", cfg.watchdog.timeout_s)
        self.cfg, self.valves, self.safe, self.regulator = cfg, valves, safe, regulator
        self._factory, self._worker = factory, worker
        self._task: Any = None
        self.guards_regulator = False  # the device took the analog output's expiration state

    async def _setup(self) -> None:
        await self._worker.run(self._open)

    def _open(self) -> None:
        from nidaqmx.constants import Level, WatchdogAOExpirState  # noqa: PLC0415
        from nidaqmx.error_codes import DAQmxErrors as E  # noqa: PLC0415, N817
        from nidaqmx.types import AOExpirationState, DOExpirationState  # noqa: PLC0415


        try:
            task = self._factory(self.cfg.device, f"fluidsense-wdt-{self.cfg.device}", self.timeout_s)
        except Exception as exc:
            if getattr(exc, "error_code", None) == E.WATCHDOG_TIMER_NOT_SUPPORTED:
                raise ConfigError(f"driver: {self.cfg.device} has no watchdog timer, so nothing vents the gripper if "
                                  "the PC or the daemon dies; set driver.watchdog.enabled: false to run it anyway "
                                  "(its lines then keep their last level)") from exc
            raise translate(exc, self.name) from exc
        try:
            task.cfg_watchdog_do_expir_states([
                DOExpirationState(physical_channel=self.cfg.physical("line", w.line, w.port),
                                  expiration_state=Level.HIGH if w.level(self.safe[v]) else Level.LOW)
                for v, w in self.valves.items()])
            if self.regulator is not None:
                self._guard_regulator(task, AOExpirationState, WatchdogAOExpirState)
            task.start()
        except Exception as exc:
            task.close()
            raise translate(exc, self.name) from exc
        self._task = task

    def _guard_regulator(self, task: Any, state: type, kind: Any) -> None:
        w = self.regulator
        volts = w.input == "voltage"
        zero = w.to_signal(0.0) * (1.0 if volts else 1e-3)  # DAQmx: V or A
        try:
            task.cfg_watchdog_ao_expir_states([state(physical_channel=self.cfg.physical("ao", w.analog_output),
                                                     expiration_state=zero,
                                                     output_type=kind.VOLTAGE if volts else kind.CURRENT)])
            self.guards_regulator = True
        except Exception as exc:  # noqa: BLE001 - X Series boards guard digital lines only
            log.warning("%s: the device sets no analog output on expiry (%s): the regulator keeps its last setpoint "
                        "while the valves isolate it", self.name, str(exc).splitlines()[0] if str(exc) else exc)

    def _reset(self) -> None:
        if self._task.expired:
            raise DriverError(f"{self.name}: the DAQ's watchdog expired: it set the valve lines to their safe "
                              f"levels by itself (no reset for {self.timeout_s:g} s)")
        self._task.reset_timer()

    async def _kick(self) -> None:
        await self._worker.run(self._reset)

    async def _ensure_running(self) -> None:
        await self._worker.run(self._clear)

    def _clear(self) -> None:
        if self._task.expired:  # an expired device ignores digital writes until cleared
            self._task.clear_expiration()
            log.warning("%s: expiration cleared; the lines hold their safe levels until written", self.name)

    async def _stop(self) -> None:

        task, self._task = self._task, None
        if task is not None:
            await self._worker.run(close_task, task)  # disarmed: the service vented before it stops
        self._worker.close()
