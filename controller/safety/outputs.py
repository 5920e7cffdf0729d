"""The device's truth, kept fresh: the valve outputs read back once per heartbeat period,
and the box watchdog kicked four times per timeout. Both are started from the sample
loop and run beside it, so both stop when the loop stalls: a box watchdog that stops
hearing the loop vents the cell, which is the point.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable
from typing import Any

from fluidsense.common.faults import FaultKind
from fluidsense.drivers.backend import Backend

from ..path import Events
from .latch import SafetyLatch, vented_word

log = logging.getLogger(__name__)


def _word(open_: bool) -> str:
    return "open" if open_ else "closed"


class OutputWatch:
    def __init__(self, backend: Backend, latch: SafetyLatch, events: Events, period_s: float):
        """``events``: where what the read-back finds is said (``log``)."""
        self.backend, self.latch, self._events, self.period_s = backend, latch, events, period_s
        self._readback: asyncio.Task | None = None
        self._kick: asyncio.Task | None = None
        self._next_read = 0.0
        self._next_kick = 0.0
        self._disagreed = False  # the last read-back disagreed with what was commanded
        self._vented_seen: bool | None = None  # the last ``vented`` said while latched

    def on_block(self, now: float) -> None:
        dog = self.backend.watchdog
        if dog is not None and now >= self._next_kick and (self._kick is None or self._kick.done()):
            self._next_kick = now + dog.timeout_s / 4
            self._kick = asyncio.create_task(self._guarded(dog.kick(), "kicking the box watchdog"))
        if self.backend.valves.reports_outputs and now >= self._next_read and \
                (self._readback is None or self._readback.done()):
            self._next_read = now + self.period_s
            self._readback = asyncio.create_task(self._read(now))

    def tripped(self) -> None:
        """The latch has just reported what the device says: say changes from here on."""
        self._vented_seen = self.latch.vented()

    async def _read(self, now: float) -> None:
        valves = self.backend.valves
        wrong = await self._guarded(valves.disagreement(), "reading the valve outputs back")
        # twice in a row: one read can meet a write still on its way to a UR box's outputs
        if wrong and self._disagreed and not self.latch.tripped:
            commanded = valves.state
            self.latch.defer(f"the device reports {', '.join(f'{v} {_word(o)}' for v, o in wrong.items())}; "
                             f"commanded {', '.join(f'{v} {_word(commanded[v])}' for v in wrong)}",
                             FaultKind.COMMAND, now)
        self._disagreed = bool(wrong)
        vented = self.latch.vented()
        if self.latch.tripped and vented != self._vented_seen:
            self._vented_seen = vented
            self._events.emit("log", {"level": "INFO" if vented else "WARNING",
                                      "message": f"{self.latch.fault.kind} fault: vented {vented_word(vented)} as the "
                                      "device reports", "vented": vented_word(vented), "outputs": valves.reported})

    async def _guarded(self, work: Awaitable[Any], what: str) -> Any:
        try:
            async with asyncio.timeout(max(1.0, self.period_s)):
                return await work
        except asyncio.CancelledError:
            raise
        except Exception as exc:  # noqa: BLE001 - the outputs are then unknown; the source faults a lost link
            log.debug("%s failed: %s", what, exc)
            return None

    async def stop(self) -> None:
        for task in (self._readback, self._kick):
            if task is not None:
                task.cancel()
                try:
                    await task
                except (asyncio.CancelledError, Exception):  # noqa: BLE001 - stopping anyway
                    pass
        self._readback = self._kick = None
