"""The DAQmx calls every task of the driver makes the same way: NI's errors as ours (by
their code), a task stopped and closed, and one thread per task for its blocking calls (a
read waits for a block by design; a USB device's on-demand write takes a round trip)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from fluidsense.common.errors import (
    ConfigError,
    DeviceTimeoutError,
    DriverError,
    LinkLostError,
)


class BufferOverflowError(DriverError):
    """The input buffer filled before the loop read it: samples were lost."""


def nidaqmx_package():
    try:
        import nidaqmx  # noqa: PLC0415 - only a cell that asks for this driver needs NI's package
    except ImportError as exc:
        raise ConfigError("driver.kind: nidaqmx needs NI's Python package: pip install 'fluidsense[nidaqmx]' (and "
                          "the NI-DAQmx runtime from NI)") from exc
    return nidaqmx


def translate(exc: Exception, what: str) -> Exception:
    """A DAQmx error as one of ours, by its code (nidaqmx.error_codes.DAQmxErrors)."""
    from nidaqmx.error_codes import DAQmxErrors as E  # noqa: PLC0415, N817
    from nidaqmx.errors import DaqNotFoundError  # noqa: PLC0415

    code = getattr(exc, "error_code", None)
    text = f"{what}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
    if isinstance(exc, DaqNotFoundError):
        return ConfigError(f"driver: {text} (install the NI-DAQmx runtime)")
    if code in (E.SAMPLES_NO_LONGER_AVAILABLE, E.ACQ_STOPPED_TO_PREVENT_INPUT_BUFFER_OVERWRITE,
                E.ACQ_STOPPED_TO_PREVENT_INPUT_BUFFER_OVERWRITE_ONE_DATA_XFER_MECH):
        return BufferOverflowError(f"{what}: the input buffer overflowed: samples were lost (the loop fell more "
                                   "than driver.buffer_s behind); acquisition restarts")
    if code == E.SAMPLES_NOT_YET_AVAILABLE:
        return DeviceTimeoutError(text)
    if code == E.DEVICE_REMOVED:
        return LinkLostError(f"{text} (unplugged?)")
    if code in (E.INVALID_DEVICE_ID, E.PHYSICAL_CHAN_DOES_NOT_EXIST):
        return ConfigError(f"driver: {text}")
    return DriverError(text)


class TaskThread:
    """One thread for one task's blocking calls, in order."""

    def __init__(self, name: str):
        self._pool = ThreadPoolExecutor(1, thread_name_prefix=name)

    async def run(self, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        return await asyncio.get_running_loop().run_in_executor(self._pool, lambda: fn(*args, **kwargs))

    def close(self) -> None:
        self._pool.shutdown(wait=False)


def close_task(task: Any) -> None:
    try:
        task.stop()
    finally:
        task.close()
