"""The safety latch: the one place where a fault is latched, the safe state commanded and
confirmed by the device, and the fault cleared (docs/safety.md).

A fault latches once: later faults while latched are logged, not re-latched, so the
first cause stays visible. Tripping stops the sequence (``before_vent``), commands the
safe state (actuator vented, tank isolated, flow stopped, arm stopped), reads the valve
outputs back, publishes the fault and releases whoever waits (``after_vent``). Whether
the cell is vented is never assumed: it is what the device last reported, read after
the vent was commanded, and "unknown" while the device cannot be read (the link is down)
or cannot report its outputs at all. A latched fault is cleared only once the device has
confirmed the safe positions.

A fault found where it cannot be latched at once (synchronous code: a sink or the
publisher raising, a read-back that disagrees) is deferred and latched by the loop
after its block.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from typing import Any

from fluidsense.common.errors import FaultError
from fluidsense.common.faults import Fault, FaultKind
from fluidsense.drivers.backend import Backend

log = logging.getLogger(__name__)

#: commanding the safe state may not hold the sample loop longer than this (a device that
#: hangs is a lost link: the box watchdog vents)
SAFE_STATE_TIMEOUT_S = 2.0

Hook = Callable[[Fault, dict[str, Any]], None]


def vented_word(vented: bool | None) -> bool | str:
    """How ``vented`` is published: true, false, or "unknown"."""
    return "unknown" if vented is None else vented


class SafetyLatch:
    def __init__(self, backend: Backend, wake: asyncio.Event):
        """``wake``: set when a deferred fault waits for the loop (virtual time parks it)."""
        self.backend = backend
        self.fault: Fault | None = None
        self.vent_t: float | None = None  # sample time the safe state was commanded
        self._vent_mono: float | None = None  # ... and its time.monotonic(), to date the read-backs
        self._deferred: Fault | None = None
        self._wake = wake
        #: run on a new fault, before the safe state (stop the sequence: it must command nothing more)
        self.before_vent: list[Callable[[Fault], None]] = []
        #: run after it, with the fault event (publish it, end the cycle, release the waits)
        self.after_vent: list[Hook] = []

    @property
    def tripped(self) -> bool:
        return self.fault is not None

    @property
    def last_vent(self) -> tuple[Fault, float] | None:
        """The latched fault and the sample time its safe state was commanded."""
        return None if self.fault is None else (self.fault, self.vent_t)

    def vented(self) -> bool | None:
        """True when the device reports every valve in its safe position, False when it
        reports otherwise, None when it cannot tell: it cannot report its outputs, has not
        been read since the vent was commanded, or its last read failed."""
        valves = self.backend.valves
        if not valves.reports_outputs or valves.reported is None or valves.report_error is not None:
            return None
        if self._vent_mono is not None and valves.reported_at < self._vent_mono:
            return None
        return valves.reports_safe(valves.reported)

    async def trip(self, fault: Fault, now: float) -> None:
        """Latch ``fault``, stop the sequence, vent, confirm, and tell everyone; only the
        first fault does: later ones while latched are logged."""
        if self.fault is not None:
            log.debug("%s while %s is latched: %s", fault.kind, self.fault.kind, fault.detail)
            return
        self.fault, self.vent_t, self._vent_mono = fault, now, time.monotonic()
        log.error("FAULT %s at t=%.3f: %s", fault.kind, fault.t, fault.detail)
        for hook in self.before_vent:
            hook(fault)
        await self.command_safe_state(now)
        vented = self.vented()
        valves = self.backend.valves
        if vented is False:
            log.error("the safe state was commanded but the device reports %s", valves.reported)
        event = {"kind": fault.kind, "channel": fault.channel, "fault_t_s": fault.t, "vent_t_s": now,
                 "detail": fault.detail, "vented": vented_word(vented), "outputs": valves.reported,
                 "outputs_age_s": valves.age_s()}
        if vented is None and valves.reports_outputs:
            event["while_unknown"] = self.describe_unknown()
        for after in self.after_vent:
            after(fault, event)

    def defer(self, detail: str, kind: FaultKind, now: float) -> None:
        """A fault found outside the loop's flow: latched by the loop after its next block."""
        if self._deferred is None:
            self._deferred = Fault(kind, None, now, detail)
        self._wake.set()

    async def trip_deferred(self, now: float) -> None:
        deferred, self._deferred = self._deferred, None
        if deferred is not None:
            await self.trip(deferred, now)

    async def command_safe_state(self, now: float) -> None:
        """Safe state now, bounded in time; a failure is logged (the fault says it)."""
        try:
            async with asyncio.timeout(SAFE_STATE_TIMEOUT_S):
                await self.backend.safe_state(now)
        except Exception as exc:  # noqa: BLE001 - whatever failed, the latch stays and says so
            log.error("could not confirm the safe state: %s (%s)", exc, self.describe_unknown())

    def describe_unknown(self) -> str:
        """What the outputs may be while the device cannot be read."""
        dog = self.backend.watchdog
        if dog is not None:
            return (f"the outputs stay as last set until the control box's watchdog sets them safe, "
                    f"{dog.timeout_s:g} s after the service's last heartbeat")
        return ("the outputs stay as last set until the link returns (no box-side watchdog: only a "
                "normally-open vent path vents without the service)")

    def clear(self) -> Fault | None:
        """Clear the latched fault; refused until the device has confirmed the safe state.
        Returns the fault cleared."""
        fault = self.fault
        if fault is None:
            return None
        valves = self.backend.valves
        if valves.reports_outputs and self.vented() is not True:
            state = "its outputs cannot be read (link down?)" if self.vented() is None else \
                f"it reports {valves.reported}"
            raise FaultError(f"reset refused: the device has not confirmed the safe state since the "
                             f"{fault.kind} fault: {state}")
        log.warning("fault reset by operator: %s: %s", fault.kind, fault.detail)
        self.fault = self.vent_t = self._vent_mono = None
        return fault
