"""systemd readiness and watchdog (``Type=notify``), on the documented sd_notify protocol.

sd_notify(3): a datagram of newline-separated ``KEY=VALUE`` assignments sent to the
AF_UNIX socket named by ``$NOTIFY_SOCKET`` (a leading ``@`` names the abstract
namespace). ``$WATCHDOG_USEC`` is the service's ``WatchdogSec``; when
``$WATCHDOG_PID`` is set the watchdog is for that process only. systemd recommends
pinging at half the interval. The protocol is a dozen lines, so no dependency.

What the pings prove: ``LoopWatchdog.alive()`` says yes only if the sample loop
completed an iteration since the previous ping, or, in virtual time, is parked with
nothing waiting on samples (sample time stands still there by design). The pings run on
the same event loop as the sample loop, so a blocked event loop stops them too. A loop
iterating through device failures is alive: the supervisor has faulted and vented the
cell, and a restart would clear the latched fault without curing the device.
"""

from __future__ import annotations

import asyncio
import logging
import os
import socket
from collections.abc import Awaitable, Callable, Mapping
from typing import Protocol

log = logging.getLogger(__name__)


class Notifier:
    """Sends sd_notify messages; does nothing when not started by systemd."""

    def __init__(self, address: str | None, watchdog_s: float | None = None):
        self.address = address
        self.watchdog_s = watchdog_s
        self._sock: socket.socket | None = None
        self._warned = False

    @classmethod
    def from_env(cls, env: Mapping[str, str] = os.environ) -> Notifier:
        address = env.get("NOTIFY_SOCKET") or None
        return cls(address, watchdog_interval(env))

    @property
    def enabled(self) -> bool:
        return self.address is not None

    @property
    def ping_period_s(self) -> float | None:
        """systemd's advice: ping at half the watchdog timeout. None: no watchdog to feed."""
        if not self.enabled or self.watchdog_s is None:
            return None
        return self.watchdog_s / 2

    def send(self, *assignments: str) -> bool:
        """Send ``KEY=VALUE`` assignments in one datagram; False when it could not be sent
        (logged once: a lost notification must never stop the daemon)."""
        if self.address is None:
            return False
        try:
            if self._sock is None:
                target = "\0" + self.address[1:] if self.address.startswith("@") else self.address
                sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
                self._sock = sock  # before connect: a refused connection is closed below with it
                sock.connect(target)
            self._sock.send("\n".join(assignments).encode())
            return True
        except OSError as exc:
            if not self._warned:
                log.warning("sd_notify to %s failed: %s", self.address, exc)
                self._warned = True
            self.close()
            return False

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


def watchdog_interval(env: Mapping[str, str] = os.environ, pid: int | None = None) -> float | None:
    """The service's watchdog timeout in seconds, or None when there is none for us."""
    usec = env.get("WATCHDOG_USEC")
    if not usec:
        return None
    owner = env.get("WATCHDOG_PID")
    if owner and owner.strip() != str(pid if pid is not None else os.getpid()):
        return None
    try:
        value = int(usec)
    except ValueError:
        log.warning("ignoring WATCHDOG_USEC=%r: not an integer", usec)
        return None
    return value / 1e6 if value > 0 else None


class LoopState(Protocol):
    """What the watchdog reads from the sample loop (controller/sampling/loop.py)."""

    ticks: int
    running: bool
    virtual: bool
    idle: bool


class LoopWatchdog:
    """Decides, once per ping period, whether the sample loop has shown it is alive."""

    def __init__(self, loop: LoopState):
        self._loop = loop
        self._seen = loop.ticks
        self.stalled = False

    def alive(self) -> bool:
        loop = self._loop
        ticks = loop.ticks
        progressed, self._seen = ticks != self._seen, ticks
        ok = loop.running and (progressed or (loop.virtual and loop.idle))
        if ok == self.stalled:  # log the change only, not every period
            self.stalled = not ok
            if ok:
                log.warning("watchdog: the sample loop is alive again; pinging")
            else:
                log.error("watchdog: the sample loop made no progress for a whole period; pings stopped "
                          "(systemd will restart the service)")
        return ok


async def keep_alive(notifier: Notifier, watchdog: LoopWatchdog, period_s: float,
                     sleep: Callable[[float], Awaitable[object]] = asyncio.sleep) -> None:
    """Ping ``WATCHDOG=1`` every ``period_s`` while the loop is alive; runs until cancelled."""
    while True:
        await sleep(period_s)
        if watchdog.alive():
            notifier.send("WATCHDOG=1")
