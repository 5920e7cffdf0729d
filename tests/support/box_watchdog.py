"""The emulated box in virtual time (its clock a variable the test moves), and the sorting
gripper's watchdog figures, for the box watchdog's tests in both tiers."""

from __future__ import annotations

from fluidsense.simulator.controlbox.box import ControlBox
from fluidsense.simulator.controlbox.config import ControlBoxConfig
from fluidsense.simulator.controlbox.kinematic import KinematicModel

TIMEOUT_S = 0.5
REGISTER = 200
# sorting gripper wiring: supply on 0 (normally open: energised isolates), actuate on 1
LEVELS = {0: True, 1: False}  # the safe state: tank isolated (0 high), gripper vented (1 low)
INFLATED = 0b11  # tank isolated, actuation valve open: the gripper holds pressure


class Box:
    """An emulated box with a clock the test moves, ticking like the real one."""

    def __init__(self) -> None:
        self.t = 0.0
        self.box = ControlBox(ControlBoxConfig(), KinematicModel(), clock=lambda: self.t)
        self.beats = 0
        self.last_beat = 0.0

    def run(self, seconds: float, beat_every_s: float | None = None) -> None:
        end, next_beat = self.t + seconds, self.t
        while self.t < end - 1e-9:
            if beat_every_s is not None and self.t >= next_beat:
                self.beats += 1
                self.box.model.set_general_purpose(REGISTER - 128, self.beats)
                self.last_beat = self.t
                next_beat += beat_every_s
            self.t += 0.002
            self.box.tick()

    def run_until(self, t: float) -> None:
        self.run(t - self.t)

    @property
    def outputs(self) -> int:
        return self.box.model.digital_outputs & 0b11
