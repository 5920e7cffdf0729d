"""A driver is one registry entry (drivers/registry.py): its config model names its backend
and answers what the commands ask of a cell, so nothing outside drivers/ switches on
``driver.kind``; the recording's format lives in one package (docs/architecture.md,
"Adding a driver" and "Recording").

(Its tests with real peers: tests/system/test_driver_registry.py.)
"""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest
from fluidsense.controller.config import load_cell_config
from fluidsense.drivers.registry import ENTRIES, DriverEntry, kinds
from fluidsense.drivers.ur.dashboard import Robot
from support.cli import run_cli
from support.harness import CONFIG, PROFILE, REPO, sim_config, write_cell

# everything of ours outside drivers/: the product's other parts, the studies, the examples
OUTSIDE = ("cli", "client", "common", "controller", "daemon", "simulator", "tasks", "lab", "examples")
PRODUCT = ("cli", "client", "common", "controller", "daemon", "simulator", "tasks")


def _sources(parts):
    for part in parts:
        for path in sorted((REPO / part).rglob("*.py")):
            yield path, ast.parse(path.read_text(), str(path))


def _about_a_driver(node: ast.AST) -> bool:
    return "driver" in ast.unparse(node).lower()


def _displayed(tree: ast.AST) -> set[int]:
    """The nodes inside f-strings' replacement fields: a kind named in a message decides nothing."""
    return {id(n) for fv in ast.walk(tree) if isinstance(fv, ast.FormattedValue) for n in ast.walk(fv)}


def test_nothing_outside_drivers_decides_by_a_drivers_kind():
    """``driver.kind == "ur"``, ``cfg.driver.kind in (...)``, ``TABLE[driver.kind]``, a match
    on it: each is a place a new driver would have to be added by hand. Reading the kind
    for a message is allowed; so is the lab's serial board checking that it was given the
    one driver config it emulates (isinstance), never the product."""
    found = []
    for path, tree in _sources(OUTSIDE):
        shown = _displayed(tree)
        for node in ast.walk(tree):
            where = f"{path.relative_to(REPO)}:{getattr(node, 'lineno', '?')}"
            if isinstance(node, ast.Attribute) and node.attr == "kind" and _about_a_driver(node.value) \
                    and id(node) not in shown:
                found.append(f"{where}: {ast.unparse(node)}")
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "isinstance" \
                    and "DriverConfig" in ast.unparse(node.args[1]) and path.parts[len(REPO.parts)] in PRODUCT:
                found.append(f"{where}: {ast.unparse(node)}")
    assert not found, found


def test_the_scan_finds_a_kind_switch_where_there_is_one():
    """The walk above on the shapes it must catch (and the one it lets through)."""
    code = ('if cfg.driver.kind == "ur": pass\n'
            'port = PORTS[driver.kind]\n'
            'match self.driver.kind:\n    case "sim": pass\n'
            'x = f"driver {driver.kind!r}"\n')
    tree = ast.parse(code)
    shown = _displayed(tree)
    hits = [n.lineno for n in ast.walk(tree) if isinstance(n, ast.Attribute) and n.attr == "kind"
            and _about_a_driver(n.value) and id(n) not in shown]
    assert sorted(hits) == [1, 2, 3]


def test_every_entry_names_a_backend_that_builds_and_a_distinct_kind():
    found = kinds()
    assert len(found) == len(set(found)) == len(ENTRIES) >= 6
    for entry in ENTRIES:
        assert issubclass(entry, DriverEntry) and entry.backend_module.startswith("fluidsense.drivers.")
        assert callable(importlib.import_module(entry.backend_module).build), entry.backend_module


def _shipped(name: str, **driver):
    return load_cell_config(CONFIG / name, {"driver": driver}).driver


def test_the_ur_entry_describes_the_robot_it_connects_to():
    ur = _shipped("cell-ur-sim.yaml", host="10.0.0.7", controller="cb3", rate_hz=125.0)
    assert ur.where() == "the robot at 10.0.0.7 (RTDE port 30004)"
    assert ur.what_to_check() == ("check that the robot is on and booted, that `ping 10.0.0.7` answers, that "
                                  "nothing else holds its RTDE inputs, and driver.host in the config")
    assert ur.robot() == Robot("10.0.0.7", generation="cb3")
    box = ur.control_box()
    assert (box.host, box.modbus_port, box.arm, box.controller) == ("10.0.0.7", None, True, "cb3")
    assert ur.needs_operator() is (ur.sim_control_port is None)


def test_the_modbus_entry_describes_the_box_and_the_robot_only_with_an_arm():
    mb = _shipped("cell-modbus-sim.yaml", host="10.0.0.8", port=1502, sim_control_port=None)
    arm = "" if mb.arm is None else ", the robot's RTDE port 30004 at 10.0.0.8"
    assert mb.where() == f"the Modbus server at 10.0.0.8:1502{arm}"
    assert "on port 1502, and driver.host/port in the config" in mb.what_to_check()
    assert mb.control_box().modbus_port == 1502 and mb.needs_operator()
    no_arm = _shipped("cell-modbus-sim.yaml", host="10.0.0.8", arm=None)
    assert no_arm.robot() is None and no_arm.control_box().arm is False
    with_arm = _shipped("cell-modbus-sim.yaml", host="10.0.0.8", arm={"host": "10.0.0.9"})
    # the modbus driver's controller names what serves the registers, not the robot's generation
    assert with_arm.robot() == Robot("10.0.0.9", generation=None)


def test_a_cell_without_a_box_says_so_by_the_defaults(tmp_path):
    sim = load_cell_config(sim_config(tmp_path, seed=4)).driver
    assert (sim.where(), sim.what_to_check()) == ("the sim cell", "check the config")
    assert sim.robot() is None and sim.control_box() is None and not sim.needs_operator() and sim.live
    assert sim.samples_seed() == 4
    job = sim.for_job(9)
    assert (job.clock, job.seed, job.samples_seed()) == ("virtual", 9, 9)


def test_the_commands_name_the_drivers_that_reach_a_box_from_the_registry():
    assert kinds(DriverEntry.control_box) == ["ur", "modbus"]
    assert kinds(DriverEntry.files) == ["replay"]


def test_a_replay_entry_is_not_live_and_names_its_file(tmp_path):
    data = {"driver": {"kind": "replay", "file": str(tmp_path / "gone.mcap")},
            "profile": str(PROFILE)}
    with pytest.raises(Exception, match=r"driver\.file: .*gone\.mcap"):
        load_cell_config(write_cell(tmp_path, data))
    (tmp_path / "gone.mcap").write_bytes(b"")
    replay = load_cell_config(write_cell(tmp_path, data)).driver
    assert not replay.live and replay.files() == {"file": str(tmp_path / "gone.mcap")}
    assert replay.samples_seed() is None and replay.for_job(3) is replay


def test_the_mcap_format_is_handled_in_one_package():
    """Only drivers/recording/ imports the MCAP library: the format is written, read and
    bounded there and nowhere else."""
    users = []
    for path, tree in _sources((*OUTSIDE, "drivers")):
        for node in ast.walk(tree):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            if any(n == "mcap" or n.startswith("mcap.") for n in names):
                users.append(str(path.relative_to(REPO)))
    assert users and all(Path(u).parts[:2] == ("drivers", "recording") for u in users), users


@pytest.mark.parametrize("command, cell, says", [
    ("watchdog", "sim", "driver.kind: the box watchdog is for a UR control box (ur or modbus), this config's "
                        "driver is 'sim'"),
    ("simcell", "sim", "driver.kind: simcell emulates the control box of a ur or modbus driver, this config's "
                       "driver is 'sim'"),
    ("check", "replay", "driver.kind: check looks at a live cell; a recording has nothing to connect to"),
])
def test_a_command_refuses_a_driver_it_cannot_use_in_one_line(tmp_path, command, cell, says, capsys):
    """The entry decides (control_box(), live); the words are those the commands always said."""
    (tmp_path / "run.mcap").write_bytes(b"")
    path = CONFIG / "cell-sim.yaml" if cell == "sim" else write_cell(
        tmp_path, {"driver": {"kind": "replay", "file": str(tmp_path / "run.mcap")}, "profile": str(PROFILE)})
    out = run_cli(capsys, command, "--config", path, cwd=REPO)  # it refuses before it binds or asks anything
    assert out.returncode == 2 and out.stderr == f"fluidsense: error: {path}: {says}\n"
