"""The one exception root of fluidsense.

It lives in the lowest layer so that every layer (drivers, controller, tasks, the
application) raises the same family. Each subclass also inherits the builtin that
describes it, so callers that only know Python's builtins still catch it.
"""

from __future__ import annotations


class FluidsenseError(Exception):
    """Root of every error raised by fluidsense."""


class ConfigError(FluidsenseError, ValueError):
    """A configuration file or value is invalid. The message names file, field and reason."""


class CommandError(FluidsenseError, ValueError):
    """A command (CLI, command socket, task) is malformed or not allowed now."""


class SafetyError(FluidsenseError, ValueError):
    """A request would leave the profile's safe envelope and was refused."""


class DriverError(FluidsenseError, RuntimeError):
    """A device did not do what it was asked."""


class LinkLostError(DriverError, ConnectionError):
    """The link to a device (Modbus, RTDE, sampler process) is gone."""


class DeviceTimeoutError(DriverError, TimeoutError):
    """A device did not answer in time."""


class DeviceProtocolError(DriverError, ValueError):
    """A device sent a well-formed frame (its checksum good) whose contents cannot be true:
    a channel count, tick, rate, sequence or value it could not have. ``field`` names the
    field. Nothing it says on that link can be trusted: the driver drops the link and
    connects again."""

    def __init__(self, message: str, field: str = ""):
        super().__init__(message)
        self.field = field


class NotSupportedError(FluidsenseError, NotImplementedError):
    """The selected backend cannot do this (e.g. placing objects on a real cell)."""


class SequenceError(FluidsenseError, RuntimeError):
    """The sequencer was asked for something its state does not allow."""


class FaultError(FluidsenseError, RuntimeError):
    """The controller is in its safe state after a fault and needs a reset."""


class RecordingError(FluidsenseError, ValueError):
    """A recording cannot be written or read (not a recording, garbled, cut off before its
    config). The message names the file."""


class EndOfRecording(LinkLostError):
    """A replayed recording has no more samples: the replay driver's source is gone."""


class JobStopped(FluidsenseError, RuntimeError):
    """A job (a task, a calibration, a sensing run) ended before it finished: a fault, a
    device that failed, an operator. ``partial`` is what it had done (JSON-ready), for the
    caller to print and keep; ``fault`` the latched fault, if one stopped it."""

    def __init__(self, message: str, partial: dict, fault: dict | None = None):
        super().__init__(message)
        self.partial = partial
        self.fault = fault
