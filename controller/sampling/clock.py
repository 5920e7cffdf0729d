"""The controller's clock: sample time.

``now`` is the timestamp of the newest sample (docs/architecture.md, decision 2). A wait
returns once samples have reached its time. In virtual time asking for a wait is also
what makes samples come: ``demand`` wakes the sample loop, which otherwise parks and
lets sample time stand still.
"""

from __future__ import annotations

import asyncio


class SampleClock:
    def __init__(self) -> None:
        self.now = 0.0
        self.demand = asyncio.Event()
        self._waiters: list[tuple[float, asyncio.Future[None]]] = []

    @property
    def waiting(self) -> bool:
        return bool(self._waiters)

    async def wait(self, seconds: float) -> None:
        """Wait ``seconds`` of sample time."""
        await self.wait_until(self.now + seconds)

    async def wait_until(self, t: float) -> None:
        fut: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._waiters.append((t, fut))
        self.demand.set()
        await fut

    def advance(self, t: float) -> None:
        """Samples have reached ``t``: release every wait that is due."""
        self.now = t
        if not self._waiters:
            return
        keep = []
        for t_target, fut in self._waiters:
            if t >= t_target - 1e-12:
                if not fut.done():
                    fut.set_result(None)
            else:
                keep.append((t_target, fut))
        self._waiters = keep

    def fail(self, exc: BaseException) -> None:
        """Release every wait with ``exc`` (a fault, a stop): nobody is left waiting."""
        for _, fut in self._waiters:
            if not fut.done():
                fut.set_exception(exc)
        self._waiters = []
