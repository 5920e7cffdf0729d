"""Reconnecting a lost link, paced by back-off: what every production sample source does
after a loss (the polled sources of drivers/remote.py, the serial streamer). Its
settings, ``Reconnect``, are a driver config's ``reconnect`` section.

After ``lose()`` every read asks ``attempt()``, which raises ``LinkLostError`` at once
until a reconnection has succeeded. Attempts run in a task of their own, because opening
links and starting a sampler process takes longer than the controller waits for one
block; between failed attempts the wait doubles from ``first_s`` up to ``max_s``.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable

from fluidsense.common.errors import LinkLostError
from fluidsense.common.models import Real, StrictModel
from pydantic import Field

log = logging.getLogger(__name__)


class Reconnect(StrictModel):
    """After a lost link the source tries again, waiting ``first_s``, then twice as long
    each time up to ``max_s``. The cell stays in FAULT until an operator resets it."""

    first_s: Real = Field(0.5, gt=0, le=60)
    max_s: Real = Field(10.0, gt=0, le=600)
    connect_timeout_s: Real = Field(15.0, gt=0, le=120, description="time allowed to connect each time")


class Reconnector:
    """``connect``: opens everything again (and closes what it opened when it fails)."""

    def __init__(self, name: str, cfg: Reconnect, connect: Callable[[], Awaitable[None]]):
        self.name = name
        self.cfg = cfg
        self._connect = connect
        #: why the link is down; None while it is up
        self.lost: LinkLostError | None = None
        self._retry_at = 0.0
        self._backoff = cfg.first_s
        self._task: asyncio.Task[None] | None = None

    def lose(self, exc: LinkLostError) -> None:
        """The link is gone (the caller closes what is left of it). The first attempt waits
        ``first_s``."""
        if self.lost is None:
            log.error("%s: link lost: %s", self.name, exc)
            self._retry_at = asyncio.get_running_loop().time() + self.cfg.first_s
            self._backoff = self.cfg.first_s
        self.lost = exc

    async def attempt(self) -> None:
        """Returns once reconnected; otherwise raises LinkLostError at once, starting an
        attempt in the background when the back-off allows one."""
        loop = asyncio.get_running_loop()
        task = self._task
        if task is not None and task.done():
            self._task = None
            exc = task.exception() if not task.cancelled() else asyncio.CancelledError()
            if exc is None:
                log.warning("%s: reconnected", self.name)
                self.lost = None
                return
            self._backoff = min(2 * self._backoff, self.cfg.max_s)
            self._retry_at = loop.time() + self._backoff
            log.warning("%s: reconnection failed (%s); next attempt in %.1f s", self.name, exc, self._backoff)
            raise LinkLostError(f"{self.name}: reconnection failed: {exc}") from exc
        if task is None and loop.time() >= self._retry_at:
            self._task = asyncio.create_task(self._connect(), name=f"{self.name}-reconnect")
        state = "reconnecting" if self._task is not None else f"next attempt in {self._retry_at - loop.time():.1f} s"
        raise LinkLostError(f"{self.name}: disconnected ({self.lost}); {state}") from self.lost

    async def cancel(self) -> None:
        """Stop an attempt in progress; ``connect`` closes what it opened."""
        task, self._task = self._task, None
        if task is None:
            return
        task.cancel()
        try:
            await task
        except (asyncio.CancelledError, Exception):  # noqa: BLE001 - stopping anyway: the outcome no longer matters
            pass
