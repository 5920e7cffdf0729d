"""The simulated cell as an ordinary backend: the same device interfaces as real drivers.

Samples are "hardware timed": sample k is taken at exactly k / rate_hz seconds. In
virtual time a block is produced as soon as it is asked for; in real time the source
waits until the wall clock has reached the block's last sample, as a DAQ would.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

import numpy as np

from ..base import Backend, SampleBlock, SampleSource, SceneControl, ValveBank, Regulator
from ..config import SimDriverConfig
from ..hardware import Hardware
from .actuators import volume_law
from .gas import ATMOSPHERE, REGULATOR, Link, Network, VolumeLaw
from .plant import Plant
from .sensor import SensorModel

log = logging.getLogger(__name__)

VALVES = ("supply", "actuate")
CHANNELS = ("p_act", "p_tank")


class SimCell:
    """Plant, sensors and random streams of one simulated cell."""

    def __init__(self, cfg: SimDriverConfig, hw: Hardware):
        self.cfg = cfg
        self.hw = hw
        c = hw.circuit
        self.p_atm = c.p_atm
        seeds = np.random.SeedSequence(cfg.seed).spawn(3)
        self.rng_regulator = np.random.default_rng(seeds[0])
        self.sensor_act = SensorModel(hw.sensor, np.random.default_rng(seeds[1]))
        self.sensor_tank = SensorModel(hw.tank_sensor, np.random.default_rng(seeds[2]))
        self.scene = cfg.scene
        law = volume_law(hw.actuator, cfg.scene, self.p_atm)
        r_valve = c.valve_resistance_pa_s_per_m3
        r_res = c.resistor_pa_s_per_m3
        r_vent = r_valve + (r_res if c.resistor_position == "downstream" else 0.0)
        tank, act = 0, 1
        links = [
            Link(REGULATOR, tank, c.supply_resistance_pa_s_per_m3, "supply", True, "supply"),
            Link(tank, act, r_valve + r_res, "actuate", True, "actuate"),
            Link(act, ATMOSPHERE, r_vent, "actuate", False, "vent"),
        ]
        if c.leak_resistance_pa_s_per_m3 is not None:
            links.append(Link(act, ATMOSPHERE, c.leak_resistance_pa_s_per_m3, None, True, "leak"))
        net = Network(["tank", "actuator"], [VolumeLaw.constant(c.tank_m3, self.p_atm), law], links,
                      p_atm=self.p_atm, p_std=self.p_atm)
        self.plant = Plant(net, dict.fromkeys(VALVES, False), p_reg_abs=self.p_atm,
                           regulator_tau_s=c.regulator_tau_s)
        self.setpoint_pa = 0.0
        self.regulator_error_pa = 0.0
        self.dt = 1.0 / cfg.rate_hz
        self.k_next = 0  # index of the next sample to deliver
        # Samples are computed in chunks ahead of delivery; a command that lands inside
        # the chunk drops the rest of it, so what is delivered always reflects every
        # command issued before it.
        self._chunk = max(cfg.block_size, int(round(0.1 * cfg.rate_hz)))
        self._cache_t = np.empty(0)
        self._cache_v = np.empty((0, 2))
        self._cache_true = np.empty((0, 2))
        self._cache_pos = 0

    @property
    def t_next(self) -> float:
        return self.k_next * self.dt

    @property
    def t_last(self) -> float:
        """Time of the last delivered sample (commands cannot act before it)."""
        return (self.k_next - 1) * self.dt

    def next_block(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The next n samples: (t, readings[n, 2]) with readings (p_act, p_tank) in Pa."""
        if len(self._cache_t) - self._cache_pos < n:
            self._fill(n)
        sl = slice(self._cache_pos, self._cache_pos + n)
        self._cache_pos += n
        self.k_next += n
        return self._cache_t[sl], self._cache_v[sl]

    def true_pressures(self) -> np.ndarray:
        """True gauge pressures (p_act, p_tank) of the last delivered sample (for tests)."""
        return self._cache_true[self._cache_pos - 1]

    def _fill(self, n_min: int) -> None:
        # Stop the chunk before the next known event: a later command may still land
        # before that event, and the plant cannot undo an event it has applied.
        t_event = self.plant.next_event_time
        n = self._chunk
        if t_event < (self.k_next + n) * self.dt:
            n = int(np.ceil(t_event / self.dt - 1e-9)) - self.k_next
        n = max(n_min, n)
        k = np.arange(self.k_next, self.k_next + n)
        t = k * self.dt
        state = self.plant.sample(t)
        p_abs = self.plant.pressures_abs(state)
        p_act, p_tank = p_abs[1] - self.p_atm, p_abs[0] - self.p_atm
        self._cache_t = t
        self._cache_true = np.column_stack([p_act, p_tank])
        self._cache_v = np.column_stack([self.sensor_act.read(t, p_act), self.sensor_tank.read(t, p_tank)])
        self._cache_pos = 0

    def _invalidate(self, t_event: float) -> None:
        """Drop cached samples at or after ``t_event``; they are recomputed with the event."""
        if self._cache_pos < len(self._cache_t) and self._cache_t[-1] >= t_event:
            keep = int(np.searchsorted(self._cache_t, t_event, side="left"))
            keep = max(keep, self._cache_pos)
            self._cache_t = self._cache_t[:keep]
            self._cache_v = self._cache_v[:keep]
            self._cache_true = self._cache_true[:keep]
            self.plant.rewind(float(self._cache_t[keep - 1]) if keep > 0 else self.t_last)

    def command_valve(self, valve: str, open_: bool, t: float) -> None:
        if valve == "supply" and open_ and not self.plant.valves["supply"]:
            # a new charge: the regulator lands slightly differently each time
            sd = self.hw.circuit.regulator_repeatability_kpa * 1e3
            self.regulator_error_pa = float(self.rng_regulator.normal(0.0, sd)) if sd > 0 else 0.0
            self._schedule_regulator(t)
        t_eff = max(t, self.t_last) + self.hw.circuit.valve_delay_s
        self._invalidate(t_eff)
        self.plant.schedule_valve(t_eff, valve, open_)

    def command_setpoint(self, pressure_pa: float, t: float) -> None:
        self.setpoint_pa = pressure_pa
        self._schedule_regulator(t)

    def _schedule_regulator(self, t: float) -> None:
        target = self.p_atm + self.setpoint_pa + (self.regulator_error_pa if self.setpoint_pa else 0.0)
        t_eff = max(t, self.t_last)
        self._invalidate(t_eff)
        self.plant.schedule_regulator(t_eff, target)

    def set_scene(self, scene, t: float) -> None:
        law = volume_law(self.hw.actuator, scene, self.p_atm)
        self.scene = scene
        t_eff = max(t, self.t_last)
        self._invalidate(t_eff)
        self.plant.schedule_law(t_eff, "actuator", law)


class SimSource(SampleSource):
    channels = CHANNELS

    def __init__(self, cell: SimCell):
        super().__init__("sim-source")
        self.cell = cell
        self.rate_hz = cell.cfg.rate_hz
        self.virtual = cell.cfg.clock == "virtual"
        self._seq = 0
        self._wall_t0: float | None = None

    async def _setup(self) -> None:
        self._wall_t0 = asyncio.get_running_loop().time() - self.cell.t_next

    async def _read_block(self) -> SampleBlock:
        t, values = self.cell.next_block(self.cell.cfg.block_size)
        if not self.virtual:
            loop = asyncio.get_running_loop()
            delay = self._wall_t0 + float(t[-1]) - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
        else:
            await asyncio.sleep(0)  # let the rest of the daemon run between blocks
        self._seq += 1
        return SampleBlock(self._seq, t, values, CHANNELS)


class SimValves(ValveBank):
    def __init__(self, cell: SimCell):
        super().__init__("sim-valves", VALVES)
        self.cell = cell

    async def _set(self, valve: str, open: bool, t: float) -> None:
        self.cell.command_valve(valve, open, t)


class SimRegulator(Regulator):
    def __init__(self, cell: SimCell):
        super().__init__("sim-regulator")
        self.cell = cell

    async def _set_setpoint(self, pressure_pa: float, t: float) -> None:
        self.cell.command_setpoint(pressure_pa, t)


class SimScene(SceneControl):
    def __init__(self, cell: SimCell):
        super().__init__("sim-scene")
        self.cell = cell

    async def set_scene(self, scene, t: float) -> None:
        self.cell.set_scene(scene, t)

    def truth(self) -> dict[str, Any]:
        return self.cell.scene.model_dump()


def build(cfg: SimDriverConfig, hw: Hardware) -> Backend:
    cell = SimCell(cfg, hw)
    return Backend(name="sim", source=SimSource(cell), valves=SimValves(cell),
                   regulator=SimRegulator(cell), scene=SimScene(cell), extras={"cell": cell})
