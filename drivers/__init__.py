"""Device drivers: the lowest layer. Never imports the controller or the tasks."""

from .base import (Backend, Device, FlowController, Regulator, SampleBlock, SampleSource,
                   SceneControl, ValveBank)
from .errors import (CommandError, ConfigError, DeviceTimeoutError, DriverError, FaultError,
                     FluidsenseError, LinkLostError, NotSupportedError, SafetyError, SequenceError)

__all__ = [
    "Backend", "Device", "FlowController", "Regulator", "SampleBlock", "SampleSource",
    "SceneControl", "ValveBank",
    "CommandError", "ConfigError", "DeviceTimeoutError", "DriverError", "FaultError",
    "FluidsenseError", "LinkLostError", "NotSupportedError", "SafetyError", "SequenceError",
]
