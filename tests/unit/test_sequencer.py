"""The valve-sequencing state machine, alone (pure) and driving the simulated cell."""

from __future__ import annotations

import numpy as np
import pytest
from fluidsense.common.errors import SequenceError
from fluidsense.common.scenes import CylinderScene
from fluidsense.controller.config import SequenceConfig, Window
from fluidsense.controller.cycles.sequencer import (
    Sequencer,
    SetpointAction,
    State,
    ValveAction,
)

CFG = SequenceConfig(p0_kpa=63, charge_s=10, isolate_s=10, actuate_s=20, vent_s=10,
                     windows=[Window(name="eq", start_s=4, end_s=5)])


def drive(seq: Sequencer, t_from: float, t_to: float, dt: float = 0.01):
    """Feed block-end times; collect (t, commands) whenever there are any."""
    out = []
    for t in np.arange(t_from, t_to, dt):
        cmds = seq.on_time(float(t))
        if cmds:
            out.append((round(float(t), 6), cmds))
    return out


def test_cycle_runs_the_states_in_order_with_the_configured_durations():
    seq = Sequencer(CFG)
    start = seq.start(0.0)
    assert start == [ValveAction("actuate", False), SetpointAction(63e3), ValveAction("supply", True)]
    assert seq.state == State.CHARGE
    cmds = drive(seq, 0.01, 60.0)
    assert cmds == [(10.0, [ValveAction("supply", False)]),
                    (20.0, [ValveAction("actuate", True)]),
                    (40.0, [ValveAction("supply", False), ValveAction("actuate", False)])]
    tr = [(round(x.t, 6), x.source, x.target) for x in seq.drain_transitions()]
    assert tr == [(0.0, State.IDLE, State.CHARGE), (10.0, State.CHARGE, State.ISOLATE),
                  (20.0, State.ISOLATE, State.ACTUATE), (24.0, State.ACTUATE, State.HOLD),
                  (40.0, State.HOLD, State.VENT), (50.0, State.VENT, State.IDLE)]
    assert seq.t_open == pytest.approx(20.0)
    assert seq.aborted is None


@pytest.mark.parametrize("abort_at, state", [(5.0, State.CHARGE), (15.0, State.ISOLATE),
                                             (22.0, State.ACTUATE), (30.0, State.HOLD), (45.0, State.VENT)])
def test_abort_from_any_state_goes_to_vent_with_every_valve_closed(abort_at, state):
    seq = Sequencer(CFG)
    seq.start(0.0)
    drive(seq, 0.01, abort_at)
    assert seq.state == state
    cmds = seq.abort(abort_at, "operator")
    assert set(cmds) == {ValveAction("actuate", False), ValveAction("supply", False)}  # the safe positions
    assert seq.state == State.VENT
    later = drive(seq, abort_at + 0.01, abort_at + 20.0)
    assert later == []  # nothing re-opens after an abort
    assert seq.state == State.IDLE
    assert seq.aborted == "operator"
    assert seq.drain_transitions()[-1].reason == "aborted"


def test_start_while_busy_and_in_fault_is_refused():
    seq = Sequencer(CFG)
    seq.start(0.0)
    with pytest.raises(SequenceError, match="running"):
        seq.start(1.0)
    seq.fault(2.0, "over_pressure")
    assert seq.state == State.FAULT
    with pytest.raises(SequenceError, match="FAULT"):
        seq.start(3.0)
    seq.reset(4.0)
    assert seq.state == State.IDLE
    seq.start(5.0)
    assert seq.state == State.CHARGE


def test_windows_must_fit_inside_the_actuation():
    with pytest.raises(ValueError, match="after the valve closes"):
        SequenceConfig(actuate_s=3.0, windows=[Window(name="eq", start_s=4, end_s=5)])


# ------------------------------------------------------- on the simulated cell
async def _abort_mid_hold(controller):
    await controller.scene.place(CylinderScene(diameter_mm=60))
    fut = await controller.start_cycle()
    while controller.cycles.sequencer.state != State.HOLD:
        await controller.wait(0.5)
    cell = controller.backend.sim
    p_before = cell.true_pressures()[0]
    assert await controller.abort("test")
    result = await fut
    return p_before, cell.true_pressures(), result, controller.status()


def test_abort_on_the_cell_vents_the_actuator(virtual_controller):
    p_before, p_after, result, status = virtual_controller(_abort_mid_hold)
    assert p_before > 30e3  # inflated when the abort came
    assert abs(p_after[0]) < 50.0  # vented to atmosphere (Pa) by the end of VENT
    assert p_after[1] > 30e3  # the isolated tank kept its charge
    assert result.aborted == "test" and not result.ok
    assert status["state"] == "idle" and status["valves"] == {"supply": False, "actuate": False}
