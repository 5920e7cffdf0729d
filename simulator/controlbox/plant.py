"""A control box whose I/O is wired to the simulated pneumatic cell (``fluidsense simcell``).

The plant is the same ``SimulatedCell`` the in-process backend uses, stepped in the box's
time: every ``advance`` delivers the cell's samples up to now and the analog inputs
show the newest one through the sensors' transfer functions. Valves follow the digital
outputs and the regulator follows its analog output, as the ``wiring`` section of the
cell config says; the arm carries objects of the simulated work cell.
"""

from __future__ import annotations

import logging
from typing import Any

from fluidsense.common.hardware import Hardware
from fluidsense.common.wiring import Wiring
from fluidsense.simulator.cell import CellSettings, SimulatedCell
from fluidsense.simulator.controlbox.kinematic import KinematicModel
from fluidsense.simulator.controlbox.model import AnalogDomain, Pose

log = logging.getLogger(__name__)

_DOMAIN = {"voltage": AnalogDomain.VOLTAGE, "current": AnalogDomain.CURRENT}
# faults of the plant, its sensors and the arm; a lost link is the box process dying
BOX_FAULTS = ("over_pressure", "leak", "sensor_nan", "sensor_stuck", "sensor_range", "protective_stop")


class _BoxArm:
    """What the simulated cell asks of an arm: where the tool is, whether it is stopped."""

    def __init__(self, model: PlantModel):
        self._model = model

    def pose_at(self, t: float) -> Pose:
        return self._model.tcp_pose  # the box applies commands now: t is now

    @property
    def stopped(self) -> bool:
        return self._model.protective_stop

    @stopped.setter
    def stopped(self, on: bool) -> None:
        self._model.protective_stop = on


class PlantModel(KinematicModel):
    def __init__(self, hw: Hardware, wiring: Wiring, sim: CellSettings | None = None,
                 initial_pose: Pose = (0.35, 0.0, 0.25, 0.0, 3.1416, 0.0)):
        self.cell = SimulatedCell(sim or CellSettings(block_size=1), hw)
        self.cell.pace_for_real_time()
        self.wiring = wiring
        self._wired = {s.analog_input: (name, s.transfer) for name, s in wiring.sensors.items()}
        self._latest = {name: 0.0 for name in self.cell.channels}
        self._valves: dict[str, bool] = {}
        self._setpoint_pa: float | None = None
        super().__init__(initial_pose=initial_pose, analog_input_source=self._analog_in)
        self.cell.arm = _BoxArm(self)
        for ch, (_, transfer) in self._wired.items():
            self.set_analog_input(ch, domain=_DOMAIN[transfer.domain])
        if wiring.regulator is not None:
            reg = wiring.regulator
            self.set_analog_output(reg.analog_output, 0.0, _DOMAIN[reg.input])
        self.on_outputs_changed(0.0)  # de-energised valves take their rest positions

    # -- time --------------------------------------------------------------------------------
    def advance(self, t: float) -> None:
        due = int(t * self.cell.cfg.rate_hz + 1e-9) + 1 - self.cell.k_next  # samples at or before t
        if due > 0:
            _, values = self.cell.next_block(due)
            self._latest = dict(zip(self.cell.channels, values[-1].tolist()))
            self.cell._due_faults(t)
        super().advance(t)

    def _analog_in(self, channel: int, domain: AnalogDomain, t: float) -> float:
        wired = self._wired.get(channel)
        if wired is None:
            return 0.0
        name, transfer = wired
        if _DOMAIN[transfer.domain] != domain:
            return 0.0  # the box measures the other domain: a sensor driving volts into a current input
        return transfer.to_signal(self._latest[name])

    # -- outputs drive the plant ----------------------------------------------------------------
    def on_outputs_changed(self, t: float) -> None:
        bits = self.digital_outputs
        for valve, w in self.wiring.valves.items():
            open_ = bool(bits >> w.output & 1) == w.open_when_energised
            if self._valves.get(valve) != open_:
                self._valves[valve] = open_
                self.cell.command_valve(valve, open_, t)
        reg = self.wiring.regulator
        if reg is not None:
            out = self.analog_output(reg.analog_output)
            p = reg.to_pa(out.value) if out.domain == _DOMAIN[reg.input] else 0.0
            if p != self._setpoint_pa:
                self._setpoint_pa = p
                self.cell.command_setpoint(p, t)

    def move_l(self, pose: Pose, speed: float, acc: float) -> None:
        super().move_l(pose, speed, acc)
        self.cell.on_arm_move(self.t)  # a closed gripper takes its object along, or loses it

    # -- the simulation's own controls (sim control channel) -------------------------------------
    def set_scene(self, scene: Any) -> None:
        self.cell.set_scene(scene, self.t)

    def set_world(self, spec: Any) -> None:
        self.cell.set_world(spec, self.t)

    def truth(self) -> dict[str, Any]:
        return self.cell.truth()

    def inject(self, fault: str, after_s: float = 0.0) -> None:
        if fault not in BOX_FAULTS:
            raise ValueError(f"unknown fault {fault!r}; known: {', '.join(BOX_FAULTS)}")
        self.cell.inject(fault, self.t + after_s)

    def clear_faults(self) -> None:
        self.cell.clear_faults()
