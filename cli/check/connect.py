"""Reaching the cell: the backend built as the config says (read-only unless the valves
are to move), connected within a timeout that names what did not answer and what to
check (the driver's entry says both: ``where()``, ``what_to_check()``)."""

from __future__ import annotations

import asyncio
import logging

from fluidsense.common.errors import DeviceTimeoutError, LinkLostError
from fluidsense.drivers.backend import Backend

log = logging.getLogger(__name__)


async def connect(backend: Backend, driver, timeout_s: float) -> None:
    """Set the backend up within ``timeout_s``; a device that does not answer raises
    DeviceTimeoutError saying which and what to check."""
    try:
        async with asyncio.timeout(timeout_s):
            await backend.setup()
    except TimeoutError as exc:
        raise driver.unreachable(exc, timeout_s) from exc
    except LinkLostError as exc:
        raise driver.unreachable(exc) from exc


def lost(driver, exc: Exception) -> DeviceTimeoutError:
    """The link went away during the check."""
    return DeviceTimeoutError(f"lost {driver.where()} during the check ({exc}): {driver.what_to_check()}")
