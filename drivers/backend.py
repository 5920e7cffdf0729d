"""One cell's devices together: set up in order, vented and closed in reverse."""

from __future__ import annotations

import logging
from dataclasses import dataclass

from .base import (
    Arm,
    BoxWatchdog,
    Device,
    FlowController,
    Regulator,
    SampleSource,
    SceneControl,
    ValveBank,
    same_family,
)

log = logging.getLogger(__name__)


@dataclass
class Backend:
    """One cell: the devices a driver provides. Optional devices are None when absent."""

    name: str
    source: SampleSource
    valves: ValveBank
    regulator: Regulator | None = None
    flow: FlowController | None = None
    scene: SceneControl | None = None
    arm: Arm | None = None
    watchdog: BoxWatchdog | None = None

    async def safe_state(self, t: float) -> bool | None:
        """Actuator vented, tank isolated, no flow commanded, arm stopped; then the valve
        outputs read back from the device. Returns True when the device confirms every
        valve in its safe position, False when it reports otherwise, None when it cannot
        report them. Tries everything, raises the first failure."""
        first: Exception | None = None
        steps = (self.valves.safe, self.flow.stop_flow if self.flow is not None else None,
                 self.arm.stop_motion if self.arm is not None else None)
        for step in steps:
            if step is None:
                continue
            try:
                await step(t)
            except Exception as exc:  # noqa: BLE001 - keep going, report after
                first = first or exc
        if first is not None:
            said = str(first)  # the valve bank's own failure says "safe state incomplete" already
            raise same_family(first, said if said.startswith("safe state") else f"safe state incomplete: {said}") \
                from first
        # the read-back comes last: it waits for the device, and stopping the arm must not
        return self.valves.reports_safe(await self.valves.read_back())

    def devices(self) -> list[Device]:
        """In set-up order. The source comes last: a production source opens the links
        and, before its first sample, puts the (already set up) valves in their safe
        positions and reads them back."""
        found = [self.valves, self.regulator, self.flow, self.scene, self.arm, self.watchdog, self.source]
        return [d for d in found if d is not None]

    async def setup(self) -> None:
        done: list[Device] = []
        try:
            for dev in self.devices():
                await dev.setup()
                done.append(dev)
        except BaseException:
            for dev in reversed(done):
                await dev.stop()
            raise

    async def stop(self, t: float | None = None) -> None:
        """Vent first, then close every device."""
        if self.valves.connected:
            try:
                await self.safe_state(t if t is not None else float("nan"))
            except Exception as exc:  # noqa: BLE001 - closing must go on
                log.error("venting at stop failed: %s", exc)
        for dev in reversed(self.devices()):
            await dev.stop()

    async def __aenter__(self) -> Backend:
        await self.setup()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()
