"""Bad configuration: a clear error naming file, field and reason, before anything starts."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from controller.config import load_cell_config, load_profile
from drivers.errors import ConfigError

from .conftest import CONFIG, PROFILE, REPO, sim_config


def write(tmp_path: Path, name: str, data) -> Path:
    path = tmp_path / name
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data))
    return path


def cell(tmp_path: Path, **changes) -> dict:
    data = yaml.safe_load(sim_config(tmp_path).read_text())
    for dotted, value in changes.items():
        node = data
        *parents, leaf = dotted.split(".")
        for p in parents:
            node = node[p]
        node[leaf] = value
    return data


def test_shipped_configs_load():
    cfg = load_cell_config(CONFIG / "cell-sim.yaml")
    assert cfg.driver.kind == "sim" and cfg.profile.name == "pneunet-gripper"
    assert cfg.profile.sequence.p0_kpa == 63.0 and cfg.profile.circuit.tank_l == 0.3
    for profile in (CONFIG / "profiles").glob("*.yaml"):
        load_profile(profile)


@pytest.mark.parametrize("dotted, value, field, reason", [
    ("publisher.colour", "red", "publisher.colour", "unknown field"),
    ("driver.rate_hz", "fast", "driver.rate_hz", "valid number"),
    ("driver.block_size", 0, "driver.block_size", "greater than or equal to 1"),
    ("driver.kind", "plc", "driver", "does not match any of the expected tags"),
    ("driver.scene", {"kind": "cylinder"}, "driver.scene.diameter_mm", "required field is missing"),
    ("driver.scene", {"kind": "cylinder", "diameter_mm": -3}, "driver.scene.diameter_mm", "greater than 0"),
])
def test_bad_cell_config_names_file_field_and_reason(tmp_path, dotted, value, field, reason):
    path = write(tmp_path, "bad.yaml", cell(tmp_path, **{dotted: value}))
    with pytest.raises(ConfigError) as err:
        load_cell_config(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: {field}: ")
    assert reason in msg


def test_missing_section(tmp_path):
    data = cell(tmp_path)
    del data["driver"]
    path = write(tmp_path, "nodriver.yaml", data)
    with pytest.raises(ConfigError, match=r"nodriver.yaml: driver: required field is missing"):
        load_cell_config(path)


@pytest.mark.parametrize("section, change, field, reason", [
    ("sequence", {"p0_kpa": 95.0}, "sequence.p0_kpa", "95.0 is outside limits"),
    ("sequence", {"method": "flow_control"}, "sequence", "needs a flow_profile"),
    ("sequence", {"windows": [{"name": "eq", "start_s": 4, "end_s": 30}]}, "sequence", "after the valve closes"),
    ("actuator", {"kind": "gripper", "v0_ml": "lots"}, "actuator.v0_ml", "valid number"),
    ("circuit", {"tank_litres": 0.3}, "circuit.tank_litres", "unknown field"),
    ("limits", {"max_kpa": 10, "min_kpa": 20}, "limits", "must be below"),
])
def test_bad_profile_names_the_profile_file(tmp_path, section, change, field, reason):
    profile = yaml.safe_load(PROFILE.read_text())
    profile[section] = {**profile[section], **change} if section != "actuator" else change
    if section == "circuit":
        profile[section] = change | {"kind": "tank"}
    ppath = write(tmp_path, "bad-profile.yaml", profile)
    path = write(tmp_path, "cell.yaml", cell(tmp_path, profile=str(ppath)))
    with pytest.raises(ConfigError) as err:
        load_cell_config(path)
    msg = str(err.value)
    assert msg.startswith(f"{ppath}: {field}: "), msg
    assert reason in msg


def test_yaml_syntax_error_gives_line_and_column(tmp_path):
    path = write(tmp_path, "broken.yaml", "driver:\n  kind: sim\n  seed: [1, 2\n")
    with pytest.raises(ConfigError, match=r"broken.yaml:\d+:\d+: YAML syntax"):
        load_cell_config(path)


def test_not_a_mapping_and_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="expected a mapping"):
        load_cell_config(write(tmp_path, "list.yaml", "- 1\n- 2\n"))
    with pytest.raises(ConfigError, match="cannot read"):
        load_cell_config(tmp_path / "nope.yaml")


def test_yaml_is_loaded_safely(tmp_path):
    """No Python objects from YAML tags: a tag is a syntax error, nothing is constructed."""
    path = write(tmp_path, "evil.yaml", "driver: !!python/object/apply:os.system ['touch pwned']\n")
    with pytest.raises(ConfigError, match="YAML syntax"):
        load_cell_config(path)
    assert not Path("pwned").exists()


def test_run_with_a_bad_config_exits_before_binding_or_moving_anything(tmp_path):
    data = cell(tmp_path, **{"driver.block_size": -1})
    path = write(tmp_path, "bad.yaml", data)
    out = subprocess.run([sys.executable, "-m", "fluidsense.cli", "run", "--config", str(path)],
                         cwd=REPO, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert f"{path}: driver.block_size: " in out.stderr
    pub_path = data["publisher"]["pub"].removeprefix("ipc://")
    assert not Path(pub_path).exists()  # no socket was ever bound
