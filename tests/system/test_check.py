"""``fluidsense check`` against the emulated control box (``fluidsense simcell``), wired as
its own config says, through the real ur and modbus drivers: a correct config passes
and leaves the cell safe, a config with swapped valve outputs fails naming the valves,
read-only mode writes nothing, a box that does not answer is exit 3, a bad config exit 2,
and Ctrl-C while pulsing still ends vented.

(Its in-process tests: tests/unit/test_check.py.)
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import threading

import pytest
from pymodbus.client import ModbusTcpClient
from support.configs import cell_config, read, whole
from support.harness import REPO, free_loopback, free_simcell, sim_config

MODBUS_PORT = 5020  # the emulated box's Modbus server for both kinds (simcell's default, the modbus config's)
OUTPUTS, SET_MASK = 1, 2  # the UR box's Modbus registers: output bits (read), set mask (write)


def check(cell, *extra: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fluidsense", "check", "--config", str(cell), "--seconds", "1",
                           *extra], capture_output=True, text=True, timeout=timeout, cwd=REPO,
                          stdin=subprocess.DEVNULL)


def problems(out: str) -> list[str]:
    lines = out.split("\nresult\n", 1)[1].splitlines()
    return [line.strip() for line in lines if line.strip() != "everything matches the config"]


def not_about_rate(found: list[str]) -> list[str]:
    """The emulated box shares two busy cores with the test: it may miss RTDE slots, which
    check rightly reports; everything else must match."""
    return [p for p in found if not p.startswith("sampling:")]


def swapped(cell, tmp_path, whole_entries: bool = False):
    """The same cell with the supply and actuate valves' outputs swapped in the wiring
    (``whole_entries``: with their open_when_energised too)."""
    supply, actuate = (read(cell)["driver"]["wiring"]["valves"][v] for v in ("supply", "actuate"))
    if whole_entries:
        valves = {"supply": whole(actuate), "actuate": whole(supply)}
    else:
        valves = {"supply": {"output": actuate["output"]}, "actuate": {"output": supply["output"]}}
    return cell_config(tmp_path, cell, driver={"wiring": {"valves": valves}})


def output_bits(host: str) -> int:
    client = ModbusTcpClient(host, port=MODBUS_PORT, timeout=5)
    assert client.connect()
    try:
        return client.read_holding_registers(OUTPUTS, count=1).registers[0]
    finally:
        client.close()


def energise(host: str, output: int) -> None:
    client = ModbusTcpClient(host, port=MODBUS_PORT, timeout=5)
    assert client.connect()
    try:
        assert not client.write_register(SET_MASK, 1 << output).isError()
    finally:
        client.close()


@pytest.mark.parametrize("kind", ["ur", "modbus"])
def test_correct_wiring_passes_and_ends_safe(kind, tmp_path):
    with free_simcell(tmp_path, kind) as (box, cell):
        r = check(cell, "--actuate", "--yes")
        # an orderly end stops the control script: no runtime error on the box (its RTDE
        # watchdog is for a daemon that dies, not one that finishes)
        assert " ERROR " not in box.log(), box.log()
        assert r.returncode in (0, 4), r.stdout + r.stderr
        assert not_about_rate(problems(r.stdout)) == [], r.stdout
        for step in ("supply open: as wired", "actuate open: as wired", "actuate closed (vents): as wired"):
            assert step in r.stdout, r.stdout
        assert "confirmed by read-back" in r.stdout
        assert "URSoftware 5.11" in r.stdout and "safety mode NORMAL" in r.stdout  # the dashboard's account
        # left safe: a read-only look afterwards finds every valve at its safe position
        r = check(cell)
        assert not_about_rate(problems(r.stdout)) == [], r.stdout
        assert "valve supply (output 0): closed, its safe position" in r.stdout
        assert "valve actuate (output 1): closed, its safe position" in r.stdout
        assert "p_act: AI0 " in r.stdout and " V -> +0." in r.stdout  # signal through the transfer, ~0 kPa


@pytest.mark.parametrize("kind", ["ur", "modbus"])
def test_read_only_changes_no_output_and_flags_unsafe_ones(kind, tmp_path):
    with free_simcell(tmp_path, kind) as (_, cell):
        host = read(cell)["driver"]["host"]
        energise(host, 1)  # actuate open, as a crashed program might leave it
        before = output_bits(host)
        r = check(cell)
        assert output_bits(host) == before
        assert r.returncode == 4, r.stdout + r.stderr
        assert "valve actuate (output 1): the device reports it open; its safe position is closed" in r.stdout
        # the fresh box leaves the normally-open supply valve de-energised, open: at rest, not held
        assert "valve supply (output 0): open, its output off (at rest" in r.stdout
        assert not any(p.startswith("valve supply") for p in problems(r.stdout)), r.stdout


@pytest.mark.parametrize("kind", ["ur", "modbus"])
def test_fresh_box_passes_the_read_only_look(kind, tmp_path):
    """A box just started has every output off: its normally-open supply valve is open and
    the actuator vented through the 3/2 actuate valve. Nothing holds anything: no problem
    about the valves, and p_act is judged as vented."""
    with free_simcell(tmp_path, kind) as (_, cell):
        host = read(cell)["driver"]["host"]
        assert output_bits(host) & 0b11 == 0  # fresh: nothing energised
        r = check(cell)
        assert output_bits(host) & 0b11 == 0  # and still nothing: read-only
        assert not_about_rate(problems(r.stdout)) == [], r.stdout
        assert r.returncode in (0, 4), r.stdout + r.stderr  # 4 only for the rate on a loaded machine
        assert "valve supply (output 0): open, its output off (at rest" in r.stdout
        assert "valve actuate (output 1): closed, its safe position" in r.stdout
        assert "p_act: AI0 " in r.stdout  # judged against 0 kPa: the actuator counts as vented


def test_a_normally_closed_supply_valve_held_open_is_flagged(tmp_path):
    """Only a valve at rest (output off) may sit away from its safe position: a normally
    closed supply valve that reads open has its output energised by something."""
    supply_nc = {"wiring": {"valves": {"supply": whole({"output": 0, "open_when_energised": True})}}}
    with free_simcell(tmp_path, "modbus", driver=supply_nc) as (_, cell):
        host = read(cell)["driver"]["host"]
        energise(host, 0)
        r = check(cell)
        assert r.returncode == 4, r.stdout + r.stderr
        assert "valve supply (output 0): the device reports it open; its safe position is closed" in r.stdout


@pytest.mark.parametrize("kind", ["ur", "modbus"])
def test_swapped_outputs_are_named(kind, tmp_path):
    with free_simcell(tmp_path, kind) as (_, cell):
        host = read(cell)["driver"]["host"]
        r = check(swapped(cell, tmp_path), "--actuate", "--yes")
        assert r.returncode == 4, r.stdout + r.stderr
        found = not_about_rate(problems(r.stdout))
        # the wiring's "safe" state energises the real actuate valve and leaves the real
        # normally-open supply valve open: pressure reaches both sensors
        assert any(p.startswith("valve supply (output 1, normally open): pressure reached p_tank") for p in found), found
        assert any(p.startswith("valve actuate (output 0): pressure reached p_act") for p in found), found
        assert "confirmed by read-back" in r.stdout
        # ended in the (miswired) config's safe state, as read back: output 1 energised, output 0 not
        assert output_bits(host) & 0b11 == 0b10


def test_swapped_valve_entries_answer_as_the_other_valve(tmp_path):
    with free_simcell(tmp_path, "modbus") as (_, cell):
        r = check(swapped(cell, tmp_path, whole_entries=True), "--actuate", "--yes")
        assert r.returncode == 4, r.stdout + r.stderr
        found = not_about_rate(problems(r.stdout))
        assert any(p.startswith("valve actuate (output 0, normally open): actuate open: answered as 'supply open' "
                                "should") and "look swapped" in p for p in found), found
        assert any(p.startswith("valve supply (output 1): supply open: no pressure answered") for p in found), found
        assert "confirmed by read-back" in r.stdout


@pytest.mark.parametrize("kind", ["ur", "modbus"])
def test_no_box_is_a_timeout_naming_the_address(kind, tmp_path):
    from support.configs import DELETE
    from support.harness import simcell_config

    host = free_loopback()
    r = check(simcell_config(tmp_path, kind, host), "--timeout", "5")
    assert r.returncode == 3, r.stdout + r.stderr
    assert host in r.stderr and "start it first, `fluidsense simcell --config` with this same file" in r.stderr
    assert "Traceback" not in r.stderr
    # a real box's config (no sim_control_port): what to check on the box
    real = simcell_config(tmp_path, kind, host, driver={"sim_control_port": DELETE})
    r = check(real, "--timeout", "5")
    assert r.returncode == 3, r.stdout + r.stderr
    assert host in r.stderr and "check that the" in r.stderr and "simcell" not in r.stderr


@pytest.mark.parametrize("kind", ["ur", "modbus"])
def test_a_job_on_a_box_that_is_not_running_says_what_check_says(kind, tmp_path):
    """`task run` on a sim config whose box is not started: a timeout (exit 3) with the
    advice check gives, not bad input (exit 2)."""
    from support.harness import simcell_config

    cell = simcell_config(tmp_path, kind, free_loopback())
    job = subprocess.run([sys.executable, "-m", "fluidsense", "task", "run", "config/tasks/sorting.yaml", "--config",
                          str(cell)], capture_output=True, text=True, timeout=120, cwd=REPO, stdin=subprocess.DEVNULL)
    looked = check(cell, "--timeout", "5")
    assert (job.returncode, looked.returncode) == (3, 3), job.stderr + looked.stderr

    from fluidsense.controller.config import load_cell_config

    hint = load_cell_config(cell).driver.emulator_hint()
    assert hint is not None and "`fluidsense simcell --config` with this same file" in hint
    for r in (job, looked):
        (line,) = [x for x in r.stderr.splitlines() if x.startswith("fluidsense: error: ")]
        assert line.startswith("fluidsense: error: cannot reach ") and line.endswith(f"): {hint}"), line


def test_silent_modbus_server_is_a_timeout(tmp_path):
    """A box that accepts the connection and never answers."""
    from support.configs import DELETE
    from support.harness import simcell_config

    host = free_loopback([MODBUS_PORT])
    # no robot: only the Modbus server is asked; a real box's config (no sim_control_port): the
    # advice is about the box
    cell = simcell_config(tmp_path, "modbus", host, driver={"arm": None, "sim_control_port": DELETE})
    with socket.create_server((host, MODBUS_PORT)) as server:
        accepted: list[socket.socket] = []
        threading.Thread(target=lambda: accepted.append(server.accept()[0]), daemon=True).start()
        r = check(cell, "--timeout", "3")
        for conn in accepted:
            conn.close()
    assert r.returncode == 3, r.stdout + r.stderr
    assert f"{host}:{MODBUS_PORT}" in r.stderr and "Modbus server is enabled" in r.stderr


def test_bad_config_is_exit_2_with_file_and_field(tmp_path):
    cell = cell_config(tmp_path, "cell-modbus-sim", check=False, driver={"wiring": {"valves": {"supply": {"output": 99}}}})
    r = check(cell)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [f"fluidsense: error: {cell}: driver.wiring.valves.supply.output: "
                                             "Input should be less than or equal to 15"]
    assert r.stdout == ""


def test_actuate_without_a_terminal_asks_and_moves_nothing(tmp_path):
    r = check(sim_config(tmp_path), "--actuate")
    assert r.returncode == 2
    assert "confirm on a terminal, or pass --yes" in r.stderr
    assert "pulsing" not in r.stdout and "connecting" not in r.stdout


def test_sim_driver_miswired_sensor_is_flagged(tmp_path):
    """The sim driver has no wiring to swap: its plant is the profile's. A vented actuator
    reading far from zero (a sensor with a large offset) is what the read-only look flags."""
    r = check(cell_config(tmp_path, sim_config(tmp_path, clock="virtual"), profile={"sensor": {"offset_kpa": 5.0}}),
              "--actuate", "--yes")
    assert r.returncode == 4, r.stdout + r.stderr
    found = problems(r.stdout)
    assert len(found) == 1 and found[0].startswith("p_act: reads +5."), found
    assert "supply open: as wired" in r.stdout and "confirmed by read-back" in r.stdout


def test_ctrl_c_while_pulsing_ends_vented(tmp_path):
    with free_simcell(tmp_path, "modbus") as (_, cell):
        host = read(cell)["driver"]["host"]
        proc = subprocess.Popen([sys.executable, "-m", "fluidsense", "check", "--config", str(cell), "--seconds",
                                 "1", "--actuate", "--yes", "--pulse-s", "2"], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, cwd=REPO, stdin=subprocess.DEVNULL)
        try:
            for line in proc.stdout:
                if line.startswith("  supply open"):  # the pulses are under way
                    break
            os.kill(proc.pid, signal.SIGINT)
            rest, err = proc.communicate(timeout=60)
        finally:
            with contextlib.suppress(ProcessLookupError):
                proc.kill()
        assert proc.returncode == 130, rest + err
        assert "actuate open" not in rest  # pulsing stopped there
        assert "every valve at its safe position, confirmed by read-back" in rest, rest + err
        assert "Traceback" not in err
        assert output_bits(host) & 0b11 == 0b01  # supply (normally open) energised: closed; actuate off: vented


@pytest.mark.parametrize("kind", ["ur", "modbus"])
def test_init_config_passes_check_against_the_box(kind, tmp_path):
    """`fluidsense init --driver KIND --out cell.yaml` in a folder of the user's; the box
    started from that file; `check --config cell.yaml` from there accepts it."""
    from fluidsense.simulator.controlbox.process import EmulatorProcess
    from support.harness import SIMCELL_PORTS

    host = free_loopback(SIMCELL_PORTS)
    r = subprocess.run([sys.executable, "-m", "fluidsense", "init", "--driver", kind, "--out", "cell.yaml", "--host",
                        host], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert r.returncode == 0, r.stderr
    box = EmulatorProcess(command=[sys.executable, "-m", "fluidsense", "simcell", "--config", "cell.yaml"],
                          cwd=tmp_path)
    box.start(timeout_s=30)
    try:
        r = subprocess.run([sys.executable, "-m", "fluidsense", "check", "--config", "cell.yaml", "--seconds", "1"],
                           capture_output=True, text=True, cwd=tmp_path, timeout=120, stdin=subprocess.DEVNULL)
        assert r.returncode in (0, 4), r.stdout + r.stderr
        assert not_about_rate(problems(r.stdout)) == [], r.stdout
        assert "connecting to " in r.stdout and host in r.stdout
    finally:
        assert box.stop() == 0, box.log()
        box.__exit__(None, None, None)
