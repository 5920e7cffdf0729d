"""``KinematicModel``: the control box's contract (model.py) with plain I/O state and a
Cartesian arm; a plant-backed box subclasses it (model.py shows how)."""

from __future__ import annotations

import logging

from fluidsense.common.errors import CommandError, SafetyError
from fluidsense.simulator.controlbox.model import (
    DIGITAL_MASK,
    N_ANALOG,
    N_GENERAL_PURPOSE,
    AnalogDomain,
    AnalogInputSource,
    AnalogSignal,
    ControlBoxModel,
    RobotMode,
    SafetyMode,
)
from fluidsense.simulator.controlbox.motion import (
    LineMove,
    Pose,
    Ramp,
    Segment,
    as_pose,
)

log = logging.getLogger(__name__)


def _check_channel(channel: int) -> int:
    if channel not in range(N_ANALOG):
        raise CommandError(f"analog channel {channel} does not exist (0..{N_ANALOG - 1})")
    return channel


class KinematicModel(ControlBoxModel):
    """Plain I/O state and an arm that moves its TCP along straight lines.

    Extension points for a plant-backed subclass (keep to these):

    - ``analog_input_source(channel, domain, t)``: returns the analog input values; it is
      sampled in ``advance`` (override ``advance`` and call ``super().advance(t)`` after
      stepping the plant to ``t``);
    - ``on_outputs_changed(t)``: called once after any client changed digital or analog
      outputs, with the model time of the change.
    """

    def __init__(self, *, initial_pose: Pose = (0.3, -0.2, 0.4, 0.0, 3.1416, 0.0),
                 analog_input_source: AnalogInputSource | None = None,
                 robot_mode: RobotMode = RobotMode.RUNNING):
        self._t = 0.0
        self._inputs = 0
        self._outputs = 0
        self._ain = [AnalogSignal(0.0, AnalogDomain.VOLTAGE) for _ in range(N_ANALOG)]
        self._aout = [AnalogSignal(0.0, AnalogDomain.VOLTAGE) for _ in range(N_ANALOG)]
        self._gp = [0] * N_GENERAL_PURPOSE
        self.analog_input_source = analog_input_source
        self._pose: Pose = as_pose(initial_pose)
        self._speed: Pose = (0.0,) * 6  # type: ignore[assignment]
        self._segment: Segment | None = None
        self._tau = 0.0
        self._fraction = 1.0
        self._robot_mode = RobotMode(robot_mode)
        self._protective = False
        self._emergency = False

    # -- time ------------------------------------------------------------------------------------
    @property
    def t(self) -> float:
        return self._t

    def advance(self, t: float) -> None:
        if t < self._t:
            raise ValueError(f"model time cannot go back from {self._t} to {t}")
        dt, self._t = t - self._t, t
        self._move(dt)
        if self.analog_input_source is not None:
            for ch, sig in enumerate(self._ain):
                value = float(self.analog_input_source(ch, sig.domain, t))
                self._ain[ch] = AnalogSignal(value, sig.domain)

    def _move(self, dt: float) -> None:
        seg = self._segment
        if seg is None:
            return
        self._tau += dt * self._fraction
        self._pose = seg.pose(self._tau)
        if self._tau >= seg.duration:
            self._segment = None
            self._speed = (0.0,) * 6  # type: ignore[assignment]
            log.debug("arm still at %s", self._pose)
        else:
            self._speed = tuple(v * self._fraction for v in seg.velocity(self._tau))  # type: ignore[assignment]

    # -- digital I/O ---------------------------------------------------------------------------
    @property
    def digital_inputs(self) -> int:
        return self._inputs

    def set_digital_inputs(self, mask: int, bits: int) -> None:
        mask &= DIGITAL_MASK
        self._inputs = (self._inputs & ~mask) | (bits & mask)

    @property
    def digital_outputs(self) -> int:
        return self._outputs

    def set_digital_outputs(self, mask: int, bits: int) -> None:
        mask &= DIGITAL_MASK
        self._outputs = (self._outputs & ~mask) | (bits & mask)

    # -- analog I/O ------------------------------------------------------------------------------
    def analog_input(self, channel: int) -> AnalogSignal:
        return self._ain[_check_channel(channel)]

    def set_analog_input(self, channel: int, value: float | None = None,
                         domain: AnalogDomain | None = None) -> None:
        old = self._ain[_check_channel(channel)]
        self._ain[channel] = AnalogSignal(old.value if value is None else float(value),
                                          old.domain if domain is None else AnalogDomain(domain))

    def analog_output(self, channel: int) -> AnalogSignal:
        return self._aout[_check_channel(channel)]

    def set_analog_output(self, channel: int, value: float, domain: AnalogDomain) -> None:
        self._aout[_check_channel(channel)] = AnalogSignal(float(value), AnalogDomain(domain))

    # -- general purpose registers -------------------------------------------------------------
    def general_purpose(self, index: int) -> int:
        return self._gp[index]

    def set_general_purpose(self, index: int, value: int) -> None:
        if not 0 <= value <= 0xFFFF:
            raise CommandError(f"general purpose register value {value} is not a uint16")
        self._gp[index] = int(value)

    # -- arm -------------------------------------------------------------------------------------
    @property
    def tcp_pose(self) -> Pose:
        return self._pose

    @property
    def tcp_speed(self) -> Pose:
        return self._speed

    @property
    def target_pose(self) -> Pose:
        target = self._segment.target() if self._segment is not None else None
        return target if target is not None else self._pose

    def set_tcp_pose(self, pose: Pose) -> None:
        """Put the TCP somewhere at once (test set-up); any motion is dropped."""
        self._pose = as_pose(pose)
        self._segment, self._speed = None, (0.0,) * 6  # type: ignore[assignment]

    def _require_may_move(self, what: str) -> None:
        if not self.may_move():
            raise SafetyError(f"{what} refused: robot mode {self.robot_mode.name}, "
                              f"safety mode {self.safety_mode.name}")

    def _start(self, segment: Segment) -> None:
        self._segment, self._tau = segment, 0.0

    def move_l(self, pose: Pose, speed: float, acc: float) -> None:
        self._require_may_move("moveL")
        target = as_pose(pose)
        if not (speed > 0 and acc > 0):
            raise CommandError(f"moveL needs speed > 0 and acceleration > 0, got {speed}, {acc}")
        # A new move starts from the current pose at rest: the ur_rtde script stops any
        # running move before it starts the next, and blending is not emulated.
        self._start(LineMove(self._pose, target, speed, acc))
        log.debug("moveL to %s at %.3f m/s, %.3f m/s^2", target, speed, acc)

    def speed_l(self, velocity: Pose, acc: float) -> None:
        self._require_may_move("speedL")
        if not acc > 0:
            raise CommandError(f"speedL needs acceleration > 0, got {acc}")
        self._start(Ramp(self._pose, self._speed_unscaled(), as_pose(velocity), acc))

    def stop(self, acc: float) -> None:
        if self._segment is None:
            return
        if not acc > 0:
            raise CommandError(f"stop needs deceleration > 0, got {acc}")
        self._start(Ramp(self._pose, self._speed_unscaled(), (0.0,) * 6, acc))

    def _speed_unscaled(self) -> Pose:
        """Velocity in segment time (the speed slider scales it on the way out)."""
        if self._fraction <= 0:
            return (0.0,) * 6  # type: ignore[return-value]
        return tuple(v / self._fraction for v in self._speed)  # type: ignore[return-value]

    def is_moving(self) -> bool:
        return self._segment is not None

    @property
    def speed_fraction(self) -> float:
        return self._fraction

    @speed_fraction.setter
    def speed_fraction(self, value: float) -> None:
        if not 0.0 <= value <= 1.0:
            raise CommandError(f"speed fraction must be in [0, 1], got {value}")
        self._fraction = float(value)

    # -- robot and safety state -----------------------------------------------------------------
    @property
    def robot_mode(self) -> RobotMode:
        return self._robot_mode

    @robot_mode.setter
    def robot_mode(self, mode: RobotMode) -> None:
        mode = RobotMode(mode)
        if mode != self._robot_mode:
            log.info("robot mode %s -> %s", self._robot_mode.name, mode.name)
        self._robot_mode = mode
        if mode != RobotMode.RUNNING:
            self._halt()

    @property
    def safety_mode(self) -> SafetyMode:
        if self._emergency:
            return SafetyMode.ROBOT_EMERGENCY_STOP
        if self._protective:
            return SafetyMode.PROTECTIVE_STOP
        return SafetyMode.NORMAL

    @property
    def protective_stop(self) -> bool:
        return self._protective

    @protective_stop.setter
    def protective_stop(self, on: bool) -> None:
        if bool(on) != self._protective:
            log.warning("protective stop %s", "ON" if on else "released")
        self._protective = bool(on)
        if on:
            self._safety_halt()

    @property
    def emergency_stop(self) -> bool:
        return self._emergency

    @emergency_stop.setter
    def emergency_stop(self, on: bool) -> None:
        if bool(on) != self._emergency:
            log.warning("emergency stop %s", "PRESSED" if on else "released")
        self._emergency = bool(on)
        if on:
            self._safety_halt()

    def _safety_halt(self) -> None:
        # A real arm brakes to rest within a few hundred ms (a category 1 or 2 stop);
        # stopping at once keeps "where did it stop" simple and never depends on the
        # speed slider.
        self._halt()

    def _halt(self) -> None:
        """Power lost or brakes on: the arm stands where it is."""
        self._segment, self._speed = None, (0.0,) * 6  # type: ignore[assignment]
