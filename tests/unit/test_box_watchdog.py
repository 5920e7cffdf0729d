"""The box vents the gripper by itself when the service stops, and the service's first act
on a link that comes back is to write the safe outputs and read them back.

The first tests run the emulated box in-process in virtual time (its clock is a
variable) on the very programs drivers/ur/watchdog.py generates. The others run
``fluidsense simcell`` in its own process against the production drivers; their times
are read on the box's own clock (its model time), the clock its watchdog keeps.

(Its tests with real peers: tests/system/test_box_watchdog.py.)
"""

from __future__ import annotations

import pytest
from fluidsense.controller.config import load_cell_config
from fluidsense.drivers.registry import build_backend
from fluidsense.drivers.ur.watchdog import runstate_program, safe_levels, watchdog_program
from fluidsense.simulator.controlbox.box import IdleProgram, RuntimeState
from fluidsense.simulator.controlbox.scriptport import ScriptServer
from fluidsense.simulator.controlbox.watchdog import WatchdogProgram
from support.box_watchdog import INFLATED, LEVELS, REGISTER, TIMEOUT_S, Box
from support.harness import CONFIG



def test_the_generated_levels_follow_the_wiring():
    cfg = load_cell_config(CONFIG / "cell-modbus-sim.yaml")
    assert safe_levels(cfg.driver.wiring.valves, cfg.profile.hardware.circuit.safe_valves) == LEVELS


def test_the_watchdog_program_vents_after_its_timeout_and_again_after_each_silence():
    b = Box()
    program = WatchdogProgram.from_source(watchdog_program(LEVELS, REGISTER, TIMEOUT_S))
    assert program.register == REGISTER and program.timeout_s == TIMEOUT_S and program.vent == LEVELS
    assert b.box.run_program(program)
    b.box.set_digital_outputs(0b11, INFLATED, "modbus")
    b.run(3.0, beat_every_s=0.1)
    assert b.outputs == INFLATED  # beating: the program leaves the outputs alone
    b.run_until(b.last_beat + TIMEOUT_S - 0.01)
    assert b.outputs == INFLATED
    b.run_until(b.last_beat + TIMEOUT_S + 0.01)
    assert b.outputs == 0b01  # silent for the timeout: vented, tank isolated
    t_vent, outputs, by = b.box.journal[-1]
    assert by == "watchdog" and outputs & 0b11 == 0b01
    assert TIMEOUT_S < t_vent - b.last_beat <= TIMEOUT_S + 2 * 0.002 + 1e-9  # seen one cycle late, vented the next
    b.run(0.5, beat_every_s=0.1)  # the service is back and inflates again
    b.box.set_digital_outputs(0b11, INFLATED, "modbus")
    b.run(1.0, beat_every_s=0.1)
    assert b.outputs == INFLATED
    b.run_until(b.last_beat + TIMEOUT_S + 0.01)
    assert b.outputs == 0b01 and program.vents == 2


def test_runstate_actions_hold_the_outputs_safe_while_no_program_runs():
    b = Box()
    b.box.run_program(IdleProgram("anything"))
    server = ScriptServer(b.box, "127.0.0.1", 0)
    server._consume(runstate_program(LEVELS))  # a secondary program: the running one goes on
    assert b.box.runtime_state == RuntimeState.PLAYING and b.box.runstate == {0: 2, 1: 1}
    b.box.set_digital_outputs(0b11, INFLATED, "rtde")
    b.run(0.1)
    assert b.outputs == INFLATED  # a program runs: outputs are the service's
    b.box.stop_program("RTDE watchdog")
    b.run(0.01)
    assert b.outputs == 0b01  # no program: safe levels
    b.box.set_digital_outputs(0b10, 0b10, "modbus")
    b.run(0.01)
    assert b.outputs == 0b01  # and held there


def test_program_integrator_beats_the_register_and_sends_nothing_to_the_box(tmp_path):
    from fluidsense.drivers.modbus.backend import ModbusHeartbeat
    from support.configs import cell_config

    cell = cell_config(tmp_path, "cell-gripper-modbus-sim", driver={"watchdog": {"program": "integrator"}})
    cfg = load_cell_config(cell)
    backend = build_backend(cfg.driver, cfg.profile.hardware)
    assert isinstance(backend.watchdog, ModbusHeartbeat) and backend.watchdog.register == REGISTER
    assert len(backend.source.on_connect) == 1  # the safe positions; no script sent
    ours = build_backend(load_cell_config(cell_config(tmp_path, "cell-gripper-modbus-sim",
                                                      driver={"watchdog": {}})).driver, cfg.profile.hardware)
    assert len(ours.source.on_connect) == 2  # the safe positions, then fluidsense's watchdog program
    assert cfg.driver.dead_link_vent().by == "box_watchdog"
    with pytest.raises(Exception, match="program: integrator is for cells without an arm"):
        cell_config(tmp_path, "cell-modbus-sim", driver={"watchdog": {"program": "integrator"}})


def test_fluidsense_watchdog_prints_what_the_driver_installs(tmp_path, capsys):
    from support.cli import run_cli
    from support.configs import cell_config
    from support.harness import REPO

    cell = cell_config(tmp_path, "cell-modbus-sim", driver={"arm": None})
    out = run_cli(capsys, "watchdog", "--config", cell, cwd=REPO)
    assert out.returncode == 0, out.stderr
    program = WatchdogProgram.from_source(out.stdout)
    assert program.vent == LEVELS and program.register == REGISTER and program.timeout_s == TIMEOUT_S
    refused = run_cli(capsys, "watchdog", "--config", CONFIG / "cell-sim.yaml", cwd=REPO)
    assert refused.returncode == 2 and "driver.kind" in refused.stderr and "Traceback" not in refused.stderr
