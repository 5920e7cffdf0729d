"""The safety latch: the one place where a fault is latched, the safe state commanded and
confirmed by the device, and the fault cleared (docs/safety.md).

A fault latches once: later faults while latched are logged, not re-latched, so the
first cause stays visible. Tripping commands the safe state (actuator vented, tank
isolated, flow stopped, arm stopped) and reads the valve outputs back. Whether the cell
is vented is never assumed: it is what the device last reported, read after the vent
was commanded, and "unknown" while the device cannot be read (the link is down) or
cannot report its outputs at all. A latched fault is cleared only once the device has
confirmed the safe positions.
"""

from __future__ import annotations

import asyncio
import logging
import time
from typing import Any

from drivers.base import Backend
from drivers.errors import FaultError
from drivers.faults import Fault

log = logging.getLogger(__name__)

#: commanding the safe state may not hold the sample loop longer than this (a device that
#: hangs is a lost link: the box watchdog vents)
SAFE_STATE_TIMEOUT_S = 2.0


def vented_word(vented: bool | None) -> bool | str:
    """How ``vented`` is published: true, false, or "unknown"."""
    return "unknown" if vented is None else vented


class SafetyLatch:
    def __init__(self, backend: Backend):
        self.backend = backend
        self.fault: Fault | None = None
        self.vent_t: float | None = None  # sample time the safe state was commanded
        self._vent_mono: float | None = None  # ... and its time.monotonic(), to date the read-backs

    @property
    def tripped(self) -> bool:
        return self.fault is not None

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

    async def trip(self, fault: Fault, now: float) -> dict[str, Any] | None:
        """Latch ``fault`` and command the safe state; the ``fault`` event to publish, or
        None when a fault was already latched."""
        if self.fault is not None:
            log.warning("fault %s while %s is latched: %s", fault.kind, self.fault.kind, fault.detail)
            return None
        self.fault, self.vent_t, self._vent_mono = fault, now, time.monotonic()
        log.error("FAULT %s at t=%.3f: %s", fault.kind, fault.t, fault.detail)
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
        return event

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
