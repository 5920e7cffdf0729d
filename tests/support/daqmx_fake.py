"""Stand-ins for ``nidaqmx.Task`` and ``nidaqmx.system.WatchdogTask``, the only things
mocked in the nidaqmx driver's tests.

NI's driver library (libnidaqmx, the NI-DAQmx runtime) cannot be installed on this
machine, and without it ``nidaqmx.Task()`` raises DaqNotFoundError. Everything above the
Task is real: NI's ``nidaqmx`` package provides the constants and the error classes the
driver uses, and every call the driver makes on a fake task is bound against the real
``nidaqmx`` method's signature, so a call that the real API would refuse (a misspelt
keyword, a missing argument) fails here too. Attributes set on ``in_stream`` must exist
on the real InStream.

The acquisition is driven by the test: ``acquire(rows)`` puts samples (V or A per
channel) in the device's buffer; a read wanting more than the buffer holds fails as
DAQmx does when its timeout passes (SAMPLES_NOT_YET_AVAILABLE), and more unread samples
than the buffer holds stop the acquisition (SAMPLES_NO_LONGER_AVAILABLE), as DAQmx does
with "do not overwrite unread samples". ``rig.lie`` changes the next block a read returns
(a device or library that says what cannot be true).

The watchdog task takes its expiration states as nidaqmx's own named tuples with its
enums (``DOExpirationState`` with a ``Level``, ``AOExpirationState`` with a
``WatchdogAOExpirState``), and ``expire()`` is the device's timer running out: the
digital lines take their expiration levels, and ``expired`` reads true until cleared.
"""

from __future__ import annotations

import inspect
import threading
from collections import deque
from typing import Any

import nidaqmx
from nidaqmx.constants import Level, WatchdogAOExpirState
from nidaqmx.error_codes import DAQmxErrors
from nidaqmx.errors import DaqError, DaqReadError
from nidaqmx.system.watchdog import WatchdogTask
from nidaqmx.task import _in_stream, _timing
from nidaqmx.task import collections as ni_collections
from nidaqmx.types import AOExpirationState, DOExpirationState


def _bind(real: Any, *args: Any, **kwargs: Any) -> dict[str, Any]:
    """The call's arguments by name, as the real method would take them (raises TypeError
    where it would)."""
    bound = inspect.signature(real).bind(None, *args, **kwargs)
    bound.apply_defaults()
    return {k: v for k, v in bound.arguments.items() if k != "self"}


class _Api:
    """Methods of one real nidaqmx class, recorded as (name, arguments) after binding."""

    def __init__(self, task: FakeTask, real_class: type):
        self._task, self._real = task, real_class

    def __getattr__(self, name: str):
        real = getattr(self._real, name)

        def call(*args: Any, **kwargs: Any) -> None:
            self._task.calls.append((name, _bind(real, *args, **kwargs)))
            self._task.on_call(name)

        return call


class _InStream:
    def __init__(self) -> None:
        object.__setattr__(self, "set", {})

    def __setattr__(self, name: str, value: Any) -> None:
        if not isinstance(getattr(_in_stream.InStream, name, None), property):
            raise AttributeError(f"nidaqmx's InStream has no property {name!r}")
        self.set[name] = value


class FakeTask:
    def __init__(self, rig: FakeRig, new_task_name: str = ""):
        _bind(nidaqmx.Task.__init__, new_task_name)
        self.rig, self.name = rig, new_task_name
        self.calls: list[tuple[str, dict[str, Any]]] = []
        self.ai_channels = _Api(self, ni_collections.AIChannelCollection)
        self.ao_channels = _Api(self, ni_collections.AOChannelCollection)
        self.do_channels = _Api(self, ni_collections.DOChannelCollection)
        self.timing = _Api(self, _timing.Timing)
        self.in_stream = _InStream()
        self.written: list[Any] = []
        self.started = self.closed = False
        self._buffer: deque[tuple[float, ...]] = deque()
        self._overflowed = False

    def on_call(self, name: str) -> None:
        self.rig.on_call(name)

    def channels(self, kind: str) -> list[dict[str, Any]]:
        return [args for name, args in self.calls if name.startswith(f"add_{kind}")]

    # ------------------------------------------------------------ the Task API used
    def start(self) -> None:
        _bind(nidaqmx.Task.start)
        self.on_call("start")
        self.started = True

    def stop(self) -> None:
        _bind(nidaqmx.Task.stop)
        self.started = False

    def close(self) -> None:
        _bind(nidaqmx.Task.close)
        self.closed = True

    def write(self, data: Any, *args: Any, **kwargs: Any) -> int:
        _bind(nidaqmx.Task.write, data, *args, **kwargs)
        self.on_call("write")
        self.written.append(data)
        return 1

    def read(self, *args: Any, **kwargs: Any) -> Any:
        got = _bind(nidaqmx.Task.read, *args, **kwargs)
        self.on_call("read")
        if self.channels("do"):  # a static output task reads back its lines' levels
            levels = self.rig.line_levels if self.rig.line_levels is not None else self.written[-1]
            return levels
        n = got["number_of_samples_per_channel"]
        with self.rig.lock:
            if self._overflowed:
                raise DaqReadError("Attempted to read samples that are no longer available.",
                                   DAQmxErrors.SAMPLES_NO_LONGER_AVAILABLE.value, 0)
            if len(self._buffer) < n:
                raise DaqReadError("Wait Until Done did not indicate all samples were acquired.",
                                   DAQmxErrors.SAMPLES_NOT_YET_AVAILABLE.value, 0)
            rows = [self._buffer.popleft() for _ in range(n)]
        per_channel = [list(col) for col in zip(*rows)]
        data = per_channel if len(per_channel) > 1 else per_channel[0]
        lie, self.rig.lie = self.rig.lie, None
        return data if lie is None else lie(data)

    def acquire(self, rows: list[tuple[float, ...]]) -> None:
        with self.rig.lock:
            self._buffer.extend(rows)
            if len(self._buffer) > self.in_stream.set["input_buf_size"]:
                self._overflowed = True


class FakeWatchdog:
    """``nidaqmx.system.WatchdogTask`` of one device."""

    def __init__(self, rig: FakeRig, *args: Any, **kwargs: Any):
        got = _bind(WatchdogTask.__init__, *args, **kwargs)
        self.rig, self.device, self.name, self.timeout = rig, got["device_name"], got["task_name"], got["timeout"]
        rig.on_call("WatchdogTask")
        self.do_states: dict[str, Level] = {}
        self.ao_states: dict[str, tuple[float, WatchdogAOExpirState]] = {}
        self.started = self.closed = False
        self.resets = self.clears = 0
        self._expired = False

    def cfg_watchdog_do_expir_states(self, *args: Any, **kwargs: Any) -> list:
        states = _bind(WatchdogTask.cfg_watchdog_do_expir_states, *args, **kwargs)["expiration_states"]
        self.rig.on_call("cfg_watchdog_do_expir_states")
        for e in states:
            assert isinstance(e, DOExpirationState) and isinstance(e.expiration_state, Level), e
            self.do_states[e.physical_channel] = e.expiration_state
        return []

    def cfg_watchdog_ao_expir_states(self, *args: Any, **kwargs: Any) -> list:
        states = _bind(WatchdogTask.cfg_watchdog_ao_expir_states, *args, **kwargs)["expiration_states"]
        self.rig.on_call("cfg_watchdog_ao_expir_states")
        for e in states:
            assert isinstance(e, AOExpirationState) and isinstance(e.output_type, WatchdogAOExpirState), e
            self.ao_states[e.physical_channel] = (float(e.expiration_state), e.output_type)
        return []

    def start(self) -> None:
        _bind(WatchdogTask.start)
        self.started = True

    def stop(self) -> None:
        _bind(WatchdogTask.stop)
        self.started = False

    def close(self) -> None:
        _bind(WatchdogTask.close)
        self.closed = True

    def reset_timer(self) -> None:
        _bind(WatchdogTask.reset_timer)
        self.resets += 1

    def clear_expiration(self) -> None:
        _bind(WatchdogTask.clear_expiration)
        self._expired = False
        self.clears += 1

    @property
    def expired(self) -> bool:
        if not self.started:  # DAQmx reads it only while the task runs
            raise DaqError("Specified property cannot be read while the task is not running.",
                           DAQmxErrors.INVALID_ATTRIBUTE_VALUE.value)
        return self._expired

    def expire(self) -> None:
        """The device's timer ran out: its lines take their expiration levels."""
        self._expired = True
        do = self.rig.task("do")
        lines = [args["lines"] for name, args in do.calls if name == "add_do_chan"]
        self.rig.line_levels = [self.do_states[line] == Level.HIGH for line in lines]


class FakeRig:
    """The tasks one backend made, by role (``ai``, ``do``, ``ao`` from their names), and
    its device's watchdog tasks (``watchdogs``; make them with ``watchdog``)."""

    def __init__(self) -> None:
        self.tasks: list[FakeTask] = []
        self.watchdogs: list[FakeWatchdog] = []
        self.fail_on: dict[str, Exception] = {}  # the next call of that name raises this
        self.line_levels: list[bool] | None = None  # what a DO read reports (default: as written)
        #: the next analog read's block as a lying device (or library) returns it: data -> data
        self.lie: Any = None
        self.lock = threading.Lock()

    def __call__(self, name: str = "") -> FakeTask:
        task = FakeTask(self, name)
        self.tasks.append(task)
        return task

    def on_call(self, name: str) -> None:
        if name in self.fail_on:
            raise self.fail_on.pop(name)

    def watchdog(self, *args: Any, **kwargs: Any) -> FakeWatchdog:
        dog = FakeWatchdog(self, *args, **kwargs)
        self.watchdogs.append(dog)
        return dog

    def task(self, role: str) -> FakeTask:
        """The newest task of a role."""
        return [t for t in self.tasks if t.name.startswith(f"fluidsense-{role}-")][-1]


def daq_error(code: DAQmxErrors, message: str = "device error") -> DaqError:
    return DaqError(message, code.value)
