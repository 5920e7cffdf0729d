"""An emulated UR e-Series control box: RTDE (30004), dashboard (29999), script port
(30003) and Modbus (502) peers that the unmodified ur_rtde and pymodbus clients talk to,
backed by a ``ControlBoxModel``. Run it as its own process: ``python -m
simulator.controlbox``; see docs/controlbox.md."""

from fluidsense.simulator.controlbox.config import AnalogScale, ControlBoxConfig
from fluidsense.simulator.controlbox.kinematic import KinematicModel
from fluidsense.simulator.controlbox.model import (
    AnalogDomain,
    AnalogInputSource,
    AnalogSignal,
    ControlBoxModel,
    RobotMode,
    SafetyMode,
)
from fluidsense.simulator.controlbox.motion import Pose

__all__ = [
    "AnalogDomain", "AnalogInputSource", "AnalogScale", "AnalogSignal", "ControlBoxConfig",
    "ControlBoxModel", "KinematicModel", "Pose", "RobotMode", "SafetyMode",
]
