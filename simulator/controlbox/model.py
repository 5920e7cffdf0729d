"""What the emulated control box knows about the world: I/O, the arm, safety.

``ControlBoxModel`` is the contract the protocol servers (RTDE, dashboard, script port,
Modbus) are written against. ``KinematicModel`` (kinematic.py) implements it with plain state and a
Cartesian arm; back it with a plant by subclassing it:

.. code-block:: python

    class PlantBox(KinematicModel):
        def __init__(self, plant):
            super().__init__(analog_input_source=self._sensor_volts)
            self.plant = plant

        def advance(self, t):              # called ~500 times a second, t never decreases
            self.plant.run_until(t)
            super().advance(t)             # moves the arm, samples the analog inputs

        def on_outputs_changed(self, t):   # a client changed a digital or analog output
            self.plant.set_valve("actuate", bool(self.digital_outputs & 0b1), t)

        def _sensor_volts(self, channel, domain, t):
            return self.plant.sensor_voltage(channel, t)

Conventions: single-threaded (the emulator's asyncio loop calls everything); SI units
inside (m, rad, s, V, A); ``t`` is seconds since the emulator started. Digital I/O is a
bit field in RTDE's order: bits 0-7 standard, 8-15 configurable, 16-17 tool.
"""

from __future__ import annotations

import abc
import enum
from collections.abc import Callable
from dataclasses import dataclass

from fluidsense.simulator.controlbox.motion import Pose

N_ANALOG = 2  # standard analog inputs and outputs on the control box
N_GENERAL_PURPOSE = 128  # Modbus registers 128-255
DIGITAL_BITS = 18  # 8 standard + 8 configurable + 2 tool
DIGITAL_MASK = (1 << DIGITAL_BITS) - 1


class AnalogDomain(enum.IntEnum):
    """UR's analog domains (Modbus registers 5/7/17/19, RTDE ``analog_io_types``)."""

    CURRENT = 0
    VOLTAGE = 1


class RobotMode(enum.IntEnum):
    """RTDE ``robot_mode`` / dashboard ``robotmode``."""

    NO_CONTROLLER = -1
    DISCONNECTED = 0
    CONFIRM_SAFETY = 1
    BOOTING = 2
    POWER_OFF = 3
    POWER_ON = 4
    IDLE = 5
    BACKDRIVE = 6
    RUNNING = 7
    UPDATING_FIRMWARE = 8


class SafetyMode(enum.IntEnum):
    """RTDE ``safety_mode`` / dashboard ``safetymode``."""

    NORMAL = 1
    REDUCED = 2
    PROTECTIVE_STOP = 3
    RECOVERY = 4
    SAFEGUARD_STOP = 5
    SYSTEM_EMERGENCY_STOP = 6
    ROBOT_EMERGENCY_STOP = 7
    VIOLATION = 8
    FAULT = 9


@dataclass(frozen=True)
class AnalogSignal:
    """One analog channel: ``value`` in V (voltage domain) or A (current domain)."""

    value: float
    domain: AnalogDomain


#: ``source(channel, domain, t) -> value`` in V or A; sampled at every ``advance``
AnalogInputSource = Callable[[int, AnalogDomain, float], float]


class ControlBoxModel(abc.ABC):
    """State of a UR control box and its arm, as the protocol servers see it."""

    # -- time ------------------------------------------------------------------------
    @property
    @abc.abstractmethod
    def t(self) -> float:
        """Time of the state (s since the emulator started)."""

    @abc.abstractmethod
    def advance(self, t: float) -> None:
        """Bring the state to time ``t`` (never earlier than ``self.t``)."""

    # -- digital I/O -------------------------------------------------------------------
    @property
    @abc.abstractmethod
    def digital_inputs(self) -> int: ...

    @abc.abstractmethod
    def set_digital_inputs(self, mask: int, bits: int) -> None:
        """Drive the input bits in ``mask`` to ``bits`` (wiring, fault injection)."""

    @property
    @abc.abstractmethod
    def digital_outputs(self) -> int: ...

    @abc.abstractmethod
    def set_digital_outputs(self, mask: int, bits: int) -> None:
        """Set the output bits in ``mask`` to ``bits`` (RTDE, Modbus masks)."""

    # -- analog I/O --------------------------------------------------------------------
    @abc.abstractmethod
    def analog_input(self, channel: int) -> AnalogSignal: ...

    @abc.abstractmethod
    def set_analog_input(self, channel: int, value: float | None = None,
                         domain: AnalogDomain | None = None) -> None:
        """Set the domain and/or the value (used when no source drives the channel)."""

    @abc.abstractmethod
    def analog_output(self, channel: int) -> AnalogSignal: ...

    @abc.abstractmethod
    def set_analog_output(self, channel: int, value: float, domain: AnalogDomain) -> None: ...

    # -- general purpose registers (Modbus 128-255, uint16) ----------------------------
    @abc.abstractmethod
    def general_purpose(self, index: int) -> int: ...

    @abc.abstractmethod
    def set_general_purpose(self, index: int, value: int) -> None: ...

    # -- the arm -------------------------------------------------------------------------
    @property
    @abc.abstractmethod
    def tcp_pose(self) -> Pose:
        """Actual TCP pose ``[x, y, z, rx, ry, rz]`` (m, rotation vector in rad)."""

    @property
    @abc.abstractmethod
    def tcp_speed(self) -> Pose:
        """Actual TCP velocity (m/s, rad/s)."""

    @property
    @abc.abstractmethod
    def target_pose(self) -> Pose:
        """Where the current motion ends (the actual pose when still or in speedl)."""

    @abc.abstractmethod
    def move_l(self, pose: Pose, speed: float, acc: float) -> None:
        """Start a straight-line move; raises SafetyError if the arm may not move."""

    @abc.abstractmethod
    def speed_l(self, velocity: Pose, acc: float) -> None:
        """Accelerate the TCP to ``velocity`` and keep it (until stop or another move)."""

    @abc.abstractmethod
    def stop(self, acc: float) -> None:
        """Decelerate to rest with ``acc`` (m/s^2)."""

    @abc.abstractmethod
    def is_moving(self) -> bool: ...

    @property
    @abc.abstractmethod
    def speed_fraction(self) -> float:
        """Speed slider, 0..1: scales the time of every motion."""

    @speed_fraction.setter
    @abc.abstractmethod
    def speed_fraction(self, value: float) -> None: ...

    # -- robot and safety state -------------------------------------------------------------
    @property
    @abc.abstractmethod
    def robot_mode(self) -> RobotMode: ...

    @robot_mode.setter
    @abc.abstractmethod
    def robot_mode(self, mode: RobotMode) -> None: ...

    @property
    @abc.abstractmethod
    def safety_mode(self) -> SafetyMode: ...

    @property
    @abc.abstractmethod
    def protective_stop(self) -> bool: ...

    @protective_stop.setter
    @abc.abstractmethod
    def protective_stop(self, on: bool) -> None: ...

    @property
    @abc.abstractmethod
    def emergency_stop(self) -> bool: ...

    @emergency_stop.setter
    @abc.abstractmethod
    def emergency_stop(self, on: bool) -> None: ...

    def on_outputs_changed(self, t: float) -> None:
        """Called once after a client (RTDE, Modbus) changed digital or analog outputs;
        ``t`` is the model time of the change. Default: nothing."""

    def may_move(self) -> bool:
        """Powered, brakes released and no safety stop."""
        return self.robot_mode == RobotMode.RUNNING and self.safety_mode in (SafetyMode.NORMAL, SafetyMode.REDUCED)
