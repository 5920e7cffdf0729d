"""The box vents the gripper by itself when the service stops, and the service's first act
on a link that comes back is to write the safe outputs and read them back.

The first tests run the emulated box in-process in virtual time (its clock is a
variable) on the very programs drivers/ur/watchdog.py generates. The others run
``fluidsense simcell`` in its own process against the production drivers; their times
are read on the box's own clock (its model time), the clock its watchdog keeps.

(Its in-process tests: tests/unit/test_box_watchdog.py.)
"""

from __future__ import annotations

import asyncio
import os
import signal
import tempfile
import time
from pathlib import Path

import pytest
from fluidsense.common import rundirs
from fluidsense.common.errors import FaultError
from fluidsense.controller.config import load_cell_config
from fluidsense.controller.service import Controller
from fluidsense.controller.telemetry import publisher
from fluidsense.drivers.sampler import source
from fluidsense.drivers.registry import build_backend
from fluidsense.drivers.ur.watchdog import safe_levels, watchdog_lines
from fluidsense.simulator.controlbox.watchdog import WatchdogProgram
from support.box_watchdog import INFLATED, LEVELS, REGISTER, TIMEOUT_S, Box
from support.harness import CONFIG, Daemon, daemon_loop_priority, free_simcell



# ------------------------------------------------------------------ against fluidsense simcell
QUICK = {"reconnect": {"first_s": 0.2, "max_s": 0.5, "connect_timeout_s": 15.0}}
NO_ARM = {**QUICK, "arm": None}


def _p_act_kpa(cfg, state) -> float:
    s = cfg.driver.wiring.sensors["p_act"]
    return s.transfer.to_pa(state["analog_inputs"][s.analog_input]["value"]) / 1e3


async def _until(predicate, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"{what} not reached within {timeout_s} s")
        await asyncio.sleep(0.02)  # polling a condition, bounded by the timeout


async def _box(call, *args):
    """The box's sim-control pipe blocks: off the event loop, one call at a time."""
    return await asyncio.to_thread(call, *args)


async def _inflate(ctrl, box, cfg) -> dict:
    await ctrl.start_cycle(hold=True)
    await _until(lambda: ctrl.cycles.sequencer.state.value == "hold", 60, "the gripper holding")
    state = await _box(box.state)
    assert state["digital_outputs"] & 0b11 == INFLATED and _p_act_kpa(cfg, state) > 20
    return state


def _journal_after(state, t: float) -> list:
    return [e for e in state["output_journal"] if e[0] > t]


def test_a_link_lost_without_a_box_watchdog_vents_as_the_first_act_when_it_returns(tmp_path):
    with free_simcell(tmp_path, "modbus", profile="sorting-gripper-quick.yaml",
                      driver={**NO_ARM, "watchdog": None}) as (box, cell):
        cfg = load_cell_config(cell)

        async def body():
            ctrl = Controller(cfg, build_backend(cfg.driver, cfg.profile.hardware))
            async with ctrl:
                await _inflate(ctrl, box, cfg)
                # the outputs are re-read periodically: wait for a report of the inflated state,
                # so that what status shows while the link is down is known
                inflated = {"supply": False, "actuate": True}
                await _until(lambda: ctrl.backend.valves.reported == inflated, 10, "a report of the inflated valves")
                down = await _box(box.network, False)
                await _until(lambda: ctrl.fault is not None, 10, "a fault")
                assert ctrl.fault.kind in ("link_lost", "no_data")
                status = ctrl.status()
                assert status["vented"] == "unknown"
                with pytest.raises(FaultError, match="not confirmed the safe state"):
                    ctrl.reset()
                still = await _box(box.state)  # nothing vents the box: the hazard this guards
                assert still["digital_outputs"] & 0b11 == INFLATED and _p_act_kpa(cfg, still) > 20
                up = await _box(box.network, True)
                await _until(lambda: ctrl.latch.vented() is True, 30, "the device confirming the safe state")
                after = await _box(box.wait_for, lambda s: _p_act_kpa(cfg, s) < 1.0, 30, "the gripper vented")
                writes = _journal_after(after, up["t"])
                # the first output the box received after the link returned was the safe state,
                # and nothing left it until the gripper had vented (how fast it vents, on the
                # box's clock: python -m lab bench faults, scenario link_back)
                assert writes and writes[0][1] & 0b11 == 0b01 and writes[0][2] == "modbus"
                assert all(w[1] & 0b11 == 0b01 for w in writes), writes
                ctrl.reset()
                result = await asyncio.wait_for(ctrl.run_cycle(), 60)
                return down, status, result

        with daemon_loop_priority(cfg):
            down, status, result = asyncio.run(asyncio.wait_for(body(), 240))
        # while down, status shows the last report from the device (inflated), and its age
        assert status["valves"] == {"supply": False, "actuate": True} and status["valves_age_s"] > 0
        assert result.ok


def test_a_link_lost_is_vented_by_the_box_watchdog_program_within_its_timeout(tmp_path):
    with free_simcell(tmp_path, "modbus", profile="sorting-gripper-quick.yaml", driver=NO_ARM) as (box, cell):
        cfg = load_cell_config(cell)
        assert cfg.driver.watchdog.timeout_s == TIMEOUT_S

        async def body():
            ctrl = Controller(cfg, build_backend(cfg.driver, cfg.profile.hardware))
            async with ctrl:
                before = await _inflate(ctrl, box, cfg)
                assert before["program"] == "fluidsense_watchdog"
                down = await _box(box.network, False)
                vented = await _box(box.wait_for, lambda s: s["digital_outputs"] & 0b11 == 0b01, 10, "the box venting")
                await _until(lambda: ctrl.fault is not None, 10, "a fault")
                fault_event = ctrl.fault
                await _box(box.network, True)
                await _until(lambda: ctrl.latch.vented() is True, 30, "the device confirming the safe state")
                ctrl.reset()
                return down, vented, fault_event

        with daemon_loop_priority(cfg):
            down, vented, fault = asyncio.run(asyncio.wait_for(body(), 240))
        (t_vent, outputs, by), = [e for e in _journal_after(vented, down["t"]) if e[2] == "watchdog"]
        # the last heartbeat came at most a kick period (timeout / 4) before the cable was pulled
        assert t_vent - down["t"] <= TIMEOUT_S + 0.01
        assert fault.kind in ("link_lost", "no_data")


@pytest.mark.parametrize("kind, driver", [("ur", QUICK), ("modbus", NO_ARM)])
def test_a_killed_daemon_is_vented_by_the_box_within_the_watchdog_timeout(kind, driver, tmp_path):
    """SIGKILL: the daemon vents nothing. With an arm, ur_rtde's script stops when its
    RTDE watchdog is no longer kicked (or its client goes); without one, fluidsense's
    watchdog program sees the heartbeat register stop. Either way the box vents."""
    with free_simcell(tmp_path, kind, profile="sorting-gripper-quick.yaml", driver=driver) as (box, cell):
        cfg = load_cell_config(cell)
        daemon = Daemon(cell, new_session=True)
        try:
            daemon.wait_welcome()
            assert "cycle_id" in daemon.request({"cmd": "cycle"})
            daemon.wait_state("hold", 60, box=box)
            before = box.state()
            assert before["digital_outputs"] & 0b11 == INFLATED
            # the endpoints' folders, named for the daemon (no other daemon's start removes
            # them while it lives; once it is killed, any may, in another test as well)
            folders = {prefix: set(Path(tempfile.gettempdir()).glob(f"{prefix}{daemon.proc.pid}-*"))
                       for prefix in (source.DIR_PREFIX, publisher.DIR_PREFIX)}
            assert all(len(found) == 1 for found in folders.values()), folders
            os.killpg(daemon.proc.pid, signal.SIGKILL)  # the daemon and its helper processes
            daemon.proc.wait(30)
            vented = box.wait_for(lambda s: s["digital_outputs"] & 0b11 == 0b01, 10, "the box venting")
            down = box.wait_for(lambda s: _p_act_kpa(cfg, s) < 1.0, 30, "the gripper vented")
        finally:
            daemon.close()
        # nobody was left to remove them; a daemon's start does (this sweep, or another
        # test's daemon starting first)
        for prefix, found in folders.items():
            rundirs.sweep_stale(prefix)
            assert not any(p.exists() for p in found), (prefix, found)
        (t_vent, _, by), *_ = _journal_after(vented, before["t"])
        assert by in ("watchdog", "runstate")
        assert t_vent - before["t"] <= TIMEOUT_S + 0.25  # the kill came after the state was read
        assert down["digital_outputs"] & 0b11 == 0b01


def test_fluidsense_watchdog_prints_the_thread_for_the_integrators_program_and_it_vents(tmp_path):
    """watchdog: null without an arm (the shipped gripper config): the box's one program is
    the integrator's. ``fluidsense watchdog`` prints the same watchdog as a thread to paste
    into it; run by the emulated box (virtual time), it vents after the timeout."""
    import subprocess
    import sys

    from support.harness import REPO

    cell = CONFIG / "cell-gripper-modbus-sim.yaml"
    out = subprocess.run([sys.executable, "-m", "fluidsense", "watchdog", "--config", str(cell)],
                         capture_output=True, text=True, timeout=60, cwd=REPO)
    assert out.returncode == 0, out.stderr
    assert not out.stdout.startswith("def ")  # statements for the integrator's def, not a program of its own
    assert "program: integrator" in out.stderr and "register 200" in out.stderr
    cfg = load_cell_config(cell)
    levels = safe_levels(cfg.driver.wiring.valves, cfg.profile.hardware.circuit.safe_valves)
    program = WatchdogProgram.from_source(out.stdout)
    assert program.vent == levels == LEVELS and program.register == REGISTER and program.timeout_s == TIMEOUT_S
    # the thread is the driver's own program's, line for line
    assert watchdog_lines(levels, REGISTER, TIMEOUT_S, "watch")[:-1] == \
        [line for line in out.stdout.splitlines() if not line.lstrip().startswith("#")][:-1]
    b = Box()
    assert b.box.run_program(program)
    b.box.set_digital_outputs(0b11, INFLATED, "modbus")
    b.run(1.0, beat_every_s=0.1)
    assert b.outputs == INFLATED
    b.run_until(b.last_beat + TIMEOUT_S + 0.01)
    assert b.outputs == 0b01  # vented, tank isolated
    # --install would replace the integrator's program: refused
    refused = subprocess.run([sys.executable, "-m", "fluidsense", "watchdog", "--config", str(cell), "--install"],
                             capture_output=True, text=True, timeout=60, cwd=REPO)
    assert refused.returncode == 2 and "--install would replace it" in refused.stderr


def test_a_cycle_beats_the_box_watchdog_before_its_first_command(tmp_path):
    """The box's watchdog program counts silence from when it was sent, at connection; the
    loop's beats start with its first block, which can come after a cycle asked for at once.
    ``ensure_running`` (called before every cycle) therefore beats once itself, on the link
    the cycle's commands then take in order, so no command meets the end of that silence.
    Without it (the base class's no-op) the register would not move here."""
    from fluidsense.drivers.modbus.backend import ModbusConnection, ModbusHeartbeat
    from pymodbus.client import ModbusTcpClient

    with free_simcell(tmp_path, "modbus", profile="sorting-gripper-quick.yaml", driver=NO_ARM) as (box, cell):
        cfg = load_cell_config(cell).driver

        def beat() -> int:
            client = ModbusTcpClient(cfg.host, port=cfg.port, timeout=5)
            assert client.connect()
            try:
                return client.read_holding_registers(cfg.watchdog.heartbeat_register, count=1).registers[0]
            finally:
                client.close()

        async def body():
            link = ModbusConnection(cfg)
            await link.open()
            dog = ModbusHeartbeat(link, cfg.watchdog)
            await dog.setup()
            try:
                before = await _box(beat)
                await dog.ensure_running()
                return before, await _box(beat)
            finally:
                await dog.stop()
                await link.close()

        before, after = asyncio.run(asyncio.wait_for(body(), 60))
        assert after == (before + 1) & 0xFFFF
