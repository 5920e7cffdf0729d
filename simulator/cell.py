"""One simulated cell: the plant, its sensors, the scene, the work cell and the arm, with
their random streams. Samples are "hardware timed": sample k is at exactly k / rate_hz
seconds; commands are events at their sample time (plus a valve's switching delay).
The device adapter that makes this an ordinary backend is drivers/sim."""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
from fluidsense.common.hardware import (
    ACTUATE,
    SUPPLY,
    FlowControlledCircuit,
    Hardware,
)
from fluidsense.common.scenes import EmptyScene, PlateScene, PullScene
from fluidsense.common.units import KPA

from .actuators import (
    contact_pressure,
    contact_truth,
    is_dynamic,
    update_step,
    volume_law,
)
from .arm import ArmModel
from .budget import SessionDraws
from .circuit import AIR, FAULT_LEAK, FAULT_SUPPLY, FAULTS, network, sensed_node
from .plant import Plant
from .sensor import SensorModel
from .world import World

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Perturbation:
    """Deviations from the calibrated state (stability studies): none by default."""

    tank_warming_k: float = 0.0
    regulator_bias_kpa: float = 0.0
    residual_kpa: float = 0.0  # the actuator starts at this gauge pressure


@dataclass(frozen=True)
class CellSettings:
    """What a simulated cell is built from. The sim driver's config (``driver: sim``) has
    the same fields and is passed as it is."""

    rate_hz: float = 1000.0
    block_size: int = 10
    seed: int = 0
    scene: Any = EmptyScene()
    perturb: Perturbation = Perturbation()


class SimulatedCell:
    """Plant, sensors and random streams of one simulated cell."""

    def __init__(self, cfg: CellSettings, hw: Hardware):
        self.cfg = cfg
        self.hw = hw
        c = hw.circuit
        self.p_atm = c.p_atm
        # children keep their keys whatever their number: a sixth stream leaves the five as before
        seeds = np.random.SeedSequence(cfg.seed).spawn(6)
        self.draws = SessionDraws(hw.budget, np.random.default_rng(seeds[5]))
        self.rng_regulator = np.random.default_rng(seeds[0])
        self.rng_flow = np.random.default_rng(seeds[4])
        self.sensors = {"p_act": SensorModel.pressure(hw.sensor, np.random.default_rng(seeds[1])),
                        "p_tank": SensorModel.pressure(hw.tank_sensor, np.random.default_rng(seeds[2])),
                        "flow": SensorModel.flow(hw.flow_sensor, np.random.default_rng(seeds[3]))}
        self.sensors["p_act"].offset += self.draws.sensor_zero_pa
        self.channels = hw.channels
        self.scene = cfg.scene
        self._nominal_scene = cfg.scene  # as set on the caliper; self.scene is where it landed
        self.scene_set_t = 0.0
        # s every valve command reaches its valve late beyond the switching delay: a busy PC's
        # command latency, which a polled driver cannot see (set by a test or a bench)
        self.command_lag_s = 0.0
        # (valve, open, commanded s, effective s) of the latest valve changes: when the valve
        # really moved, which a bench or test compares with what the controller inferred
        self.valve_log: deque[tuple[str, bool, float, float]] = deque(maxlen=64)
        net, valves = network(hw, volume_law(hw.actuator, cfg.scene, self.p_atm))
        self.act_node = net.index["actuator"]
        self.sense_node = sensed_node(hw, net)
        self.tank_node = net.index.get("tank")
        # the flow sensor sits between the actuation valve and the actuator: it sees the
        # inflow through the valve (or from the flow controller) and the vent outflow
        self.flow_links = None
        if c.flow_sensor:
            self.flow_links = {"vent": -1.0} if isinstance(c, FlowControlledCircuit) else {"actuate": 1.0, "vent": -1.0}
        tau = getattr(c, "regulator_tau_s", 0.05)
        residual = {"actuator": self.p_atm + cfg.perturb.residual_kpa * KPA} if cfg.perturb.residual_kpa else None
        self.plant = Plant(net, valves, p_reg_abs=self.p_atm, regulator_tau_s=tau, p_initial_abs=residual)
        self.valve_names = tuple(c.safe_valves)
        self.outputs = dict(c.safe_valves)  # the valve driver's output register, as commanded
        self.setpoint_pa = 0.0
        self.regulator_error_pa = 0.0
        self.detached_at: float | None = None
        self.world: World | None = None
        self.arm = ArmModel()
        self._pending_scenes: list[tuple[float, Any]] = []  # (time, scene) changes still to come
        self._faults: list[tuple[float, str]] = []  # injected faults not yet acting
        self.source_fault: str | None = None  # the source's next read fails this way
        self.dt = 1.0 / cfg.rate_hz
        self.k_next = 0  # index of the next sample to deliver
        # Samples are computed in chunks ahead of delivery; a command that lands inside
        # the chunk drops the rest of it, so what is delivered always reflects every
        # command issued before it.
        self._chunk = max(cfg.block_size, int(round(0.1 * cfg.rate_hz)))
        n_ch = len(self.channels)
        self._cache_t = np.empty(0)
        self._cache_v = np.empty((0, n_ch))
        self._cache_true = np.empty((0, n_ch))
        self._cache_pos = 0
        self._next_scene_update = float("inf")
        if is_dynamic(cfg.scene):
            self._next_scene_update = update_step(cfg.scene)

    @property
    def t_next(self) -> float:
        return self.k_next * self.dt

    @property
    def t_last(self) -> float:
        """Time of the last delivered sample (commands cannot act before it)."""
        return (self.k_next - 1) * self.dt

    # ------------------------------------------------------------- sampling
    def inject(self, kind: str, t: float, over_pa: float = 150e3) -> None:
        """Fault injection at sample time ``t`` (see FAULTS). over_pressure: the supply
        sticks open into the actuator with the regulator at ``over_pa`` (gauge)."""
        if kind not in FAULTS:
            raise ValueError(f"unknown fault {kind!r}; known: {', '.join(FAULTS)}")
        t = max(t, self.t_next)
        self._invalidate(t)
        if kind == "leak":
            self.plant.schedule_valve(t, FAULT_LEAK, True)
        elif kind == "over_pressure":
            self.plant.schedule_regulator(t, self.p_atm + over_pa)
            self.plant.schedule_valve(t, FAULT_SUPPLY, True)
        elif kind.startswith("sensor_"):
            self.sensors["p_act"].inject({"sensor_nan": "nan", "sensor_stuck": "stuck", "sensor_range": "rail"}[kind], t)
        else:  # no_data, link_lost, protective_stop act when samples reach t
            self._faults.append((t, kind))

    def clear_faults(self) -> None:
        """Undo every injected fault (the cell repaired)."""
        t = self.t_next
        self._invalidate(t)
        self.plant.schedule_valve(t, FAULT_LEAK, False)
        self.plant.schedule_valve(t, FAULT_SUPPLY, False)
        self.plant.schedule_regulator(t, self.p_atm + self.setpoint_pa)
        if self.tank_node is not None:  # an over-pressured tank is bled back to the regulator's pressure
            self.plant.schedule_pressure(t, "tank", self.p_atm + self.setpoint_pa)
        for sensor in self.sensors.values():
            sensor.fault = None
        self._faults, self.source_fault = [], None
        self.arm.stopped = False

    def _due_faults(self, t_end: float) -> None:
        due = [f for f in self._faults if f[0] <= t_end]
        self._faults = [f for f in self._faults if f[0] > t_end]
        for _, kind in due:
            if kind == "protective_stop":
                self.arm.stopped = True
            elif kind in ("no_data", "link_lost"):
                self.source_fault = kind

    def pace_for_real_time(self, chunk_s: float = 0.004, rtol: float = 1e-6) -> None:
        """Compute a few ms ahead, in short solves at a looser tolerance, for a cell stepped
        in real time beside I/O (the emulated box): a valve's transient then costs a few
        stalls of the box's loop of a few ms instead of one of 15-20 ms (one 2 s solve of the
        sorting gripper's opening at rtol 1e-9 took that here, and every Modbus read waited
        through it). rtol 1e-6 moves the sorting gripper's whole cycle by at most 0.34 Pa
        against 1e-9, far under any sensor's resolution; the short solves cost about 4x the CPU."""
        self._chunk = max(1, int(round(chunk_s * self.cfg.rate_hz)))
        self.plant.first_horizon_s = chunk_s
        self.plant.rtol = rtol

    def next_block(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The next n samples: (t, readings[n, channels]) in SI units."""
        if len(self._cache_t) - self._cache_pos < n:
            self._fill(n)
        sl = slice(self._cache_pos, self._cache_pos + n)
        self._cache_pos += n
        self.k_next += n
        return self._cache_t[sl], self._cache_v[sl]

    def true_values(self) -> dict[str, float]:
        """True values (Pa gauge, standard m^3/s) of the last delivered sample (for tests)."""
        row = self._cache_true[self._cache_pos - 1]
        return dict(zip(self.channels, row.tolist()))

    def true_pressures(self) -> np.ndarray:
        """True gauge pressures (p_act, p_tank) of the last delivered sample (for tests)."""
        tv = self.true_values()
        return np.array([tv["p_act"], tv.get("p_tank", np.nan)])

    def _fill(self, n_min: int) -> None:
        self._schedule_scene_updates(self.t_next + self._chunk * self.dt)
        # Stop the chunk before the next known event: a later command may still land
        # before that event, and the plant cannot undo an event it has applied.
        t_event = self.plant.next_event_time
        n = self._chunk
        if t_event < (self.k_next + n) * self.dt:
            n = int(np.ceil(t_event / self.dt - 1e-9)) - self.k_next
        n = max(n_min, n)
        t = np.arange(self.k_next, self.k_next + n) * self.dt
        state, flow = self.plant.sample(t, self.flow_links, flow_sources=True)
        p_abs = self.plant.pressures_abs(state)
        true = {"p_act": p_abs[self.sense_node] - self.p_atm}
        if self.tank_node is not None:
            true["p_tank"] = p_abs[self.tank_node] - self.p_atm
        if flow is not None:
            true["flow"] = flow
        self._cache_t = t
        self._cache_true = np.column_stack([true[ch] for ch in self.channels])
        self._cache_v = np.column_stack([self.sensors[ch].read(t, true[ch]) for ch in self.channels])
        self._cache_pos = 0
        self._check_detach(t[-1], true["p_act"][-1])

    def _invalidate(self, t_event: float) -> None:
        """Drop cached samples at or after ``t_event``; they are recomputed with the event."""
        if self._cache_pos < len(self._cache_t) and self._cache_t[-1] >= t_event:
            keep = max(int(np.searchsorted(self._cache_t, t_event, side="left")), self._cache_pos)
            self._cache_t = self._cache_t[:keep]
            self._cache_v = self._cache_v[:keep]
            self._cache_true = self._cache_true[:keep]
            self.plant.check_resample_from(float(self._cache_t[keep - 1]) if keep > 0 else self.t_last)

    # ------------------------------------------------------------- commands
    def command_valve(self, valve: str, open_: bool, t: float) -> None:
        if valve in self.outputs:
            self.outputs[valve] = open_
        t_eff = max(t, self.t_last) + self.hw.circuit.valve_delay_s + self.command_lag_s
        self._invalidate(t_eff)
        self.plant.schedule_valve(t_eff, valve, open_)
        self.valve_log.append((valve, open_, t, t_eff))
        if valve == ACTUATE and open_:  # a new cycle: the flow sensor repeats only within its figure
            self.sensors["flow"].gain = self.draws.flow_sensor_gain()
        warming = self.cfg.perturb.tank_warming_k
        if warming and valve == SUPPLY and not open_ and self.tank_node is not None:
            # the freshly charged tank's air settles to another temperature (approximated
            # as a step a second after isolation)
            self.plant.schedule_scale(t_eff + 1.0, "tank", (293.15 + warming) / 293.15)
        if self.world is not None and valve == ACTUATE and open_ != self.world.closed:
            # the gripper closes (or opens) on whatever is under the tool
            pose = self.arm.pose_at(t_eff)
            if open_:
                scene = self.world.close(pose, t_eff)
                obj = self.world.objects.get(self.world.holding) if self.world.holding else None
                if obj is not None and obj.slip_after_s is not None:
                    self._pending_scenes.append((t_eff + obj.slip_after_s, "slip"))
            else:
                scene = self.world.open(pose, t_eff)
                self._pending_scenes = [e for e in self._pending_scenes if e[1] != "slip"]
            self._apply_scene(scene, t_eff)

    def command_setpoint(self, pressure_pa: float, t: float) -> None:
        """A new setpoint: the regulator lands slightly differently every time it is set."""
        self.setpoint_pa = pressure_pa
        sd = getattr(self.hw.circuit, "regulator_repeatability_kpa", 0.0) * KPA
        self.regulator_error_pa = float(self.rng_regulator.normal(0.0, sd)) if sd > 0 and pressure_pa else 0.0
        t_eff = max(t, self.t_last)
        self._invalidate(t_eff)
        bias = self.cfg.perturb.regulator_bias_kpa * KPA if pressure_pa else 0.0
        session = self.draws.regulator_error_pa if pressure_pa else 0.0
        self.plant.schedule_regulator(t_eff, self.p_atm + self.setpoint_pa + self.regulator_error_pa + bias + session)

    def command_flow_profile(self, times: np.ndarray, flows: np.ndarray, t: float) -> None:
        """Flow setpoint following (times, flows) piecewise linearly; 0 after the last point."""
        c = self.hw.circuit
        gain = 1.0 + float(self.rng_flow.normal(0.0, getattr(c, "flow_repeatability", 0.0)))
        gain *= self.draws.flow_controller_gain  # the session's accuracy of rate
        tt, qq = np.asarray(times, float), np.asarray(flows, float) * gain

        def flow_of_t(x):
            return np.interp(x, tt, qq, left=0.0, right=0.0)

        t_eff = max(t, self.t_last)
        self._invalidate(t_eff)
        self.plant.schedule_flow(t_eff, flow_of_t if np.any(qq != 0) else None)
        if len(tt) and tt[-1] > t_eff:  # afterwards nothing flows: let the plant settle
            self.plant.schedule_flow(float(tt[-1]), None)

    def set_scene(self, scene, t: float) -> None:
        self._apply_scene(scene, max(t, self.t_last))

    def set_world(self, spec, t: float) -> None:
        """Lay out slots and objects; the gripper starts open and empty."""
        self.world = World(spec)
        self._pending_scenes = []
        self._apply_scene(EmptyScene(), max(t, self.t_last))

    def on_arm_move(self, t: float) -> None:
        """The arm starts a move: a closed gripper either takes its object along or, when
        it holds it too weakly, leaves it behind."""
        if self.world is None or not self.world.closed or self.world.holding is None:
            return
        p_now = self.true_values()["p_act"] if self._cache_pos > 0 else 0.0
        p_c = contact_pressure(self.hw.actuator, self.scene, self.p_atm)
        margin = abs(p_now) - abs(p_c) if p_c is not None else 0.0
        scene = self.world.move_away(t, margin / KPA)
        if scene is not None:
            self._apply_scene(scene, max(t, self.t_last))

    def _apply_scene(self, scene, t_eff: float) -> None:
        if scene != self._nominal_scene:  # placed anew (by hand): within the placement error
            self._nominal_scene = scene
            scene = self.draws.place(scene)
        elif isinstance(scene, PlateScene):  # the same setting again: the plate stays where it landed
            scene = self.scene
        law = volume_law(self.hw.actuator, scene, self.p_atm)
        self.scene, self.scene_set_t, self.detached_at = scene, t_eff, None
        self._invalidate(t_eff)
        # a moving scene before this one has its refreshes scheduled as far ahead as
        # samples were computed: from t_eff on they would put it back (a scene set for
        # later, as a closing gripper's, stays: it comes after this one)
        self.plant.cancel_laws("actuator", "refresh", t_eff)
        self.plant.schedule_law(t_eff, "actuator", law)
        self.plant.schedule_valve(t_eff, AIR, False)
        self._next_scene_update = t_eff + update_step(scene) if is_dynamic(scene) else float("inf")

    def _schedule_scene_updates(self, until: float) -> None:
        """Moving scenes change the contact law every few milliseconds; pending world
        events (a slip) happen at their time."""
        due = [e for e in self._pending_scenes if e[0] <= until]
        self._pending_scenes = [e for e in self._pending_scenes if e[0] > until]
        for t, what in due:
            scene = self.world.slip(t) if what == "slip" and self.world is not None else None
            if scene is not None:
                self._apply_scene(scene, max(t, self.t_last))
        while self._next_scene_update <= until:
            t = self._next_scene_update
            law = volume_law(self.hw.actuator, self.scene, self.p_atm, t - self.scene_set_t)
            self.plant.schedule_law(t, "actuator", law, kind="refresh")
            self._next_scene_update = t + update_step(self.scene)

    def _check_detach(self, t: float, p_act_gauge: float) -> None:
        """A pulled suction cup lets go when the pull exceeds the suction force."""
        scene = self.scene
        if not isinstance(scene, PullScene) or self.detached_at is not None:
            return
        force = float(scene.force_n(t - self.scene_set_t))
        area = self.hw.actuator.area_mm2 * 1e-6
        if force > 0 and force >= -p_act_gauge * area:
            self.detached_at = t
            log.info("suction cup detached at t=%.3f s, pull %.2f N", t, force)
            self.plant.schedule_valve(t + self.dt, AIR, True)

    def truth(self) -> dict[str, Any]:
        """The scene, plus what a bench instrument would read now (force, indentation)."""
        out = self.scene.model_dump()
        if self.world is not None:
            out["world"] = self.world.truth()
        if self.detached_at is not None:
            out["detached_at_s"] = self.detached_at
        if self._cache_pos > 0:
            p_act = self.true_values()["p_act"]
            out.update(contact_truth(self.hw.actuator, self.scene, self.p_atm, p_act, self.t_last - self.scene_set_t))
        return out
