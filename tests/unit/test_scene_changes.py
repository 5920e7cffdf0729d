"""A scene set on the simulated cell replaces the one before it at once. A moving scene
(a pull, a profile scan, a creeping object) refreshes its contact law every few
milliseconds, and the cell schedules those refreshes as far ahead as it computes samples
(a tenth of a second in virtual time, 4 ms in the emulated box): a new scene must not be
followed by the old one's refreshes."""

from __future__ import annotations

import numpy as np
import pytest
from fluidsense.cli.options import profile_path
from fluidsense.common.scenes import EmptyScene, PullScene
from fluidsense.controller.config import load_profile
from fluidsense.simulator.actuators import volume_law
from fluidsense.simulator.cell import CellSettings, SimulatedCell


def _blocks(cell: SimulatedCell, seconds: float) -> None:
    """Deliver ``seconds`` of samples block by block, as the sample loop takes them."""
    for _ in range(int(round(seconds * cell.cfg.rate_hz / cell.cfg.block_size))):
        cell.next_block(cell.cfg.block_size)


@pytest.mark.parametrize("chunk_s", [None, 0.004])  # virtual time's chunks, and the box's
def test_the_scene_after_a_moving_one_holds_from_its_first_sample(chunk_s):
    hw = load_profile(profile_path("suction-cup-pull")).hardware
    cell = SimulatedCell(CellSettings(seed=1), hw)
    if chunk_s is not None:
        cell.pace_for_real_time(chunk_s)
    cell.set_scene(PullScene(material="OO-30", rate_n_per_s=0.2, delay_s=0.0), 0.0)
    _blocks(cell, 0.55)  # mid-chunk: the pull's refreshes to its end are already scheduled
    cell.set_scene(EmptyScene(), cell.t_last)
    empty = volume_law(hw.actuator, cell.scene, cell.p_atm).volume
    actuator = cell.plant.net.index["actuator"]
    for _ in range(20):  # the 0.2 s after the change, a block at a time
        _blocks(cell, 0.01)
        assert np.array_equal(cell.plant.laws[actuator].volume, empty), cell.t_last


def test_only_the_refreshes_from_the_change_on_are_dropped():
    """A scene set for later (a gripper closing once its valve has switched) stays queued:
    a scene set before it comes first, then it."""
    hw = load_profile(profile_path("suction-cup-pull")).hardware
    plant = SimulatedCell(CellSettings(seed=1), hw).plant
    law = volume_law(hw.actuator, EmptyScene(), hw.circuit.p_atm)
    plant._events.clear()  # the cell's own start-up events are not what this is about
    plant.schedule_law(0.5, "actuator", law, kind="refresh")
    plant.schedule_law(1.0, "actuator", law)
    plant.schedule_law(1.5, "actuator", law, kind="refresh")
    assert plant.cancel_laws("actuator", "refresh", 0.6) == 1
    assert sorted((ev.t, ev.what) for ev in plant._events) == [(0.5, "law actuator refresh"), (1.0, "law actuator set")]
