"""The simulated plant's noise-free free-air rise, for the characterisation's fit of an
ISO 6358 valve's conductance (tasks/characterise.py): the rig's rise is compared with
the plant's own model of the same circuit, not with a second model written for the fit.
The simulator stays behind the sim driver (the layering's rule: only this package
imports it)."""

from __future__ import annotations

import numpy as np
from fluidsense.common.hardware import Hardware
from fluidsense.common.scenes import EmptyScene
from fluidsense.common.units import KPA
from fluidsense.simulator.timing import step_response


def free_rise(hw: Hardware, p0_pa: float, t_end_s: float, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(t s from the valve's opening, gauge Pa where the actuator's sensor is) for the
    tank at ``p0_pa`` opened onto the empty actuator at t = 0: ``hw``'s switching delay
    is taken out (the fit states its own), everything else is the cell's network."""
    c = hw.circuit.model_copy(update={"valve_delay_s": 0.0})
    resp = step_response(hw.model_copy(update={"circuit": c}), EmptyScene(), p0_pa / KPA, t_end_s, dt_s)
    return resp.t_s, resp.p_act_kpa * KPA
