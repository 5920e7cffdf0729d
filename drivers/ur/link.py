"""The daemon's side of the ur_rtde worker process (``worker.py``).

Every call has a timeout; a worker that stops sending status for ``stale_s`` (hung in a
ur_rtde call that holds its GIL, or stopped by a debugger) is treated as lost and
killed, as is one whose constructor does not answer in time.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import sys
import time
from typing import Any

from fluidsense.common.errors import DeviceTimeoutError, DriverError, LinkLostError

from ..remote import Connection

log = logging.getLogger(__name__)


class WorkerConnection(Connection):
    def __init__(self, args: dict[str, Any], name: str = "ur-rtde", call_timeout_s: float = 2.0,
                 stale_s: float = 1.0) -> None:
        self.args = args
        self.name = name
        self.call_timeout_s = call_timeout_s
        self.stale_s = max(stale_s, 5.0 / float(args.get("status_hz", 50.0)))
        self.status: dict[str, Any] | None = None
        self._status_at = 0.0
        self._status_changed = asyncio.Event()
        self._proc: asyncio.subprocess.Process | None = None
        self._reader: asyncio.Task | None = None
        self._pending: dict[int, asyncio.Future] = {}
        self._next_id = 0
        self._lost: LinkLostError | None = LinkLostError(f"{name}: not connected")

    # -- life ----------------------------------------------------------------------------------
    async def open(self) -> None:
        self._proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "fluidsense.drivers.ur.worker", json.dumps(self.args),
            stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE, limit=1 << 20)
        try:
            line = await self._proc.stdout.readline()  # the caller bounds the wait (connect timeout)
        except BaseException:
            await self._kill()
            raise
        first = json.loads(line) if line.strip() else {"error": f"exited ({await self._proc.wait()})"}
        if not first.get("ready"):
            await self._kill()
            raise LinkLostError(f"{self.name}: cannot connect to {self.args['host']}: {first.get('error')}")
        self._lost = None
        self.status, self._status_at = None, asyncio.get_running_loop().time()
        self._reader = asyncio.create_task(self._read(self._proc), name=f"{self.name}-reader")
        try:
            await self.wait_status(lambda _: True, self.stale_s)  # the arm's pose is known once set up
        except DriverError as exc:
            await self.close()
            raise LinkLostError(f"{self.name}: the worker sent no status: {exc}") from exc
        log.info("%s: connected to %s (worker %d)", self.name, self.args["host"], self._proc.pid)

    async def close(self) -> None:
        """Returns once the worker is gone, so that a new one never meets the old one's
        connections (the robot gives its RTDE input registers to one client at a time)."""
        proc, reader = self._proc, self._reader
        if proc is None:
            return
        self._proc = self._reader = None
        self._lost = self._lost or LinkLostError(f"{self.name}: closed")
        self._lose(str(self._lost))
        if proc.returncode is None:
            proc.stdin.close()  # the worker disconnects and exits at end of input
            try:
                async with asyncio.timeout(3.0):
                    await proc.wait()
            except TimeoutError:  # stuck in a ur_rtde call
                proc.kill()
                await proc.wait()
        if reader is not None:
            reader.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await reader

    async def _kill(self) -> None:
        if self._proc is not None and self._proc.returncode is None:
            self._proc.kill()
            await self._proc.wait()

    def check(self) -> None:
        if self._lost is None and asyncio.get_running_loop().time() - self._status_at > self.stale_s:
            self._lose(f"{self.name}: no status from the worker for {self.stale_s:g} s")
            if self._proc is not None and self._proc.returncode is None:
                self._proc.kill()  # hung: it will not answer again
        if self._lost is not None:
            raise self._lost

    def _lose(self, message: str) -> None:
        if self._lost is None:
            self._lost = LinkLostError(message)
            log.error("%s", message)
        for fut in self._pending.values():
            if not fut.done():
                fut.set_exception(LinkLostError(message))
        self._pending.clear()
        self._status_changed.set()

    async def _read(self, proc: asyncio.subprocess.Process) -> None:
        while line := await proc.stdout.readline():
            msg = json.loads(line)
            if "status" in msg:
                self.status = msg["status"]
                self._status_at = asyncio.get_running_loop().time()
                self._status_changed.set()
            else:
                fut = self._pending.pop(msg.get("id"), None)
                if fut is not None and not fut.done():
                    fut.set_result(msg)
        code = await proc.wait()
        if proc is self._proc:
            self._lose(f"{self.name}: worker exited ({code}): the robot closed the connection or the worker crashed")

    # -- calls ---------------------------------------------------------------------------------
    async def call(self, op: str, timeout_s: float | None = None, **fields: Any) -> dict[str, Any]:
        self.check()
        self._next_id += 1
        ident = self._next_id
        fut = asyncio.get_running_loop().create_future()
        self._pending[ident] = fut
        self._proc.stdin.write((json.dumps({"id": ident, "op": op, **fields}) + "\n").encode())
        try:
            async with asyncio.timeout(timeout_s or self.call_timeout_s):
                reply = await fut
        except TimeoutError:
            self._pending.pop(ident, None)
            raise DeviceTimeoutError(f"{self.name}: no answer to {op} within {timeout_s or self.call_timeout_s:g} s") \
                from None
        if "error" in reply:
            raise DriverError(f"{self.name}: {op}: {reply['error']}")
        return reply

    def notify(self, op: str, **fields: Any) -> None:
        """A request the worker does not answer (``kick``): written, not waited for."""
        self.check()
        self._proc.stdin.write((json.dumps({"op": op, **fields}) + "\n").encode())

    async def fresh_status(self) -> dict[str, Any]:
        """A status the worker took after everything written so far reached the robot (two
        status periods: the robot's reply to a write lags it by up to one)."""
        period = 1.0 / float(self.args.get("status_hz", 50.0))
        since = time.monotonic() + 2 * period
        return await self.wait_status(lambda s: s["t"] >= since, self.stale_s + 2 * period)

    async def wait_status(self, done, timeout_s: float) -> dict[str, Any]:
        """Wait until ``done(status)``; the status that satisfied it."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while True:
            self.check()
            if self.status is not None and done(self.status):
                return self.status
            self._status_changed.clear()
            remaining = deadline - loop.time()
            if remaining <= 0:
                raise DeviceTimeoutError(f"{self.name}: condition not reached within {timeout_s:g} s")
            try:
                async with asyncio.timeout(min(remaining, self.stale_s)):
                    await self._status_changed.wait()
            except TimeoutError:
                pass
