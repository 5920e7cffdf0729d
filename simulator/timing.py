"""Noise-free step responses of a tank circuit: the timing studies' plant.

The same network as the simulated cell (``circuit.network``: valves, resistances, the
actuator's volume law and its dashpot), started with the tank charged and the actuator
at rest, the actuation valve commanded open at t = 0 (it acts after its switching
delay). Used to predict what a reading window sees at a given time after opening and
when the actuator reaches an object, without a controller or sensor noise in the way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from fluidsense.common.hardware import ACTUATE, SUPPLY, Hardware, TankCircuit
from fluidsense.common.scenes import EmptyScene
from fluidsense.common.units import KPA

from .actuators import volume_law
from .circuit import network, sensed_node
from .plant import Plant


@dataclass(frozen=True)
class StepResponse:
    t_s: np.ndarray  # time after the valve command
    p_act_kpa: np.ndarray  # where the actuator's sensor is (the hose's valve end, or the actuator), gauge
    p_tank_kpa: np.ndarray
    v_act_ml: np.ndarray
    t_contact_s: float | None  # when the actuator first reaches the object (None: never)


def step_response(hw: Hardware, scene, p0_kpa: float, t_end_s: float, dt_s: float = 1e-3) -> StepResponse:
    """Tank at ``p0_kpa`` discharging into the actuator that closes on ``scene``."""
    c = hw.circuit
    if not isinstance(c, TankCircuit):
        raise ValueError("step responses need a tank circuit")
    law = volume_law(hw.actuator, scene, c.p_atm)
    net, valves = network(hw, law)
    p_tank_abs = c.p_atm + p0_kpa * KPA
    plant = Plant(net, valves, p_reg_abs=p_tank_abs, regulator_tau_s=c.regulator_tau_s,
                  p_initial_abs={"tank": p_tank_abs})
    plant.schedule_valve(0.0, SUPPLY, False)
    plant.schedule_valve(c.valve_delay_s, ACTUATE, True)
    t = np.arange(0.0, t_end_s + dt_s / 2, dt_s)
    state, _ = plant.sample(t)
    p = plant.pressures_abs(state) - c.p_atm
    v = plant.volumes(state, "actuator")
    return StepResponse(t, p[sensed_node(hw, net)] / KPA, p[net.index["tank"]] / KPA, v * 1e6,
                        _first_contact(hw, scene, t, v))


def _first_contact(hw: Hardware, scene, t: np.ndarray, v: np.ndarray) -> float | None:
    """First time the volume reaches the law's first breakpoint (where something is touched)."""
    if isinstance(scene, EmptyScene):
        return None
    law = volume_law(hw.actuator, scene, hw.circuit.p_atm)
    if len(law.volume) < 3:  # touching from the start
        return 0.0
    vacuum = getattr(hw.actuator, "drive", "positive") == "vacuum"
    v_contact = law.volume[-2] if vacuum else law.volume[1]
    reached = v <= v_contact if vacuum else v >= v_contact - 1e-15
    idx = np.flatnonzero(reached)
    return float(t[idx[0]]) if len(idx) else None


def window_mean(resp: StepResponse, start_s: float, length_s: float) -> float:
    """Mean actuator pressure (kPa) over a window starting ``start_s`` after the command."""
    sel = (resp.t_s >= start_s - 1e-9) & (resp.t_s < start_s + length_s - 1e-9)
    return float(resp.p_act_kpa[sel].mean())


def settling_time(resp: StepResponse, fraction: float = 0.9) -> float:
    """First time the actuator pressure reaches ``fraction`` of its final value (the last sample)."""
    final = resp.p_act_kpa[-1]
    idx = np.flatnonzero(resp.p_act_kpa >= fraction * final)
    return float(resp.t_s[idx[0]])


def settled_time(resp: StepResponse, band_kpa: float) -> float:
    """Last time the actuator pressure is more than ``band_kpa`` from its final value (the
    last sample): after it, a reading no longer depends on when it is taken."""
    final = resp.p_act_kpa[-1]
    outside = np.flatnonzero(np.abs(resp.p_act_kpa - final) > band_kpa)
    return float(resp.t_s[min(outside[-1] + 1, len(resp.t_s) - 1)]) if len(outside) else 0.0
