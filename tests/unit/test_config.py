"""Bad configuration: a clear error naming file, field and reason, before anything starts."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from fluidsense.common.errors import ConfigError
from fluidsense.controller.config import load_cell_config, load_profile
from support.configs import cell_data, profile_config, profile_data, whole
from support.cli import Ran, run_cli
from support.harness import CONFIG, REPO, sim_config


def write(tmp_path: Path, name: str, data) -> Path:
    path = tmp_path / name
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data))
    return path


def cell(tmp_path: Path, **changes) -> dict:
    """The test's sim cell with ``changes`` ("driver.block_size": -1) set, unchecked: most
    of these tests write a bad config on purpose."""
    nested: dict = {}
    for dotted, value in changes.items():
        *parents, leaf = dotted.split(".")
        node = nested
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = whole(value) if isinstance(value, dict) else value
    return cell_data(tmp_path, sim_config(tmp_path), **nested)


@pytest.mark.parametrize("name", sorted(p.name for p in CONFIG.glob("cell-*.yaml")))
def test_a_shipped_config_copied_elsewhere_loads(tmp_path, name):
    """docs/bringup.md asks for a copy of a shipped config: the copy names its profile
    (and calibrations) as the shipped file does, relative to a folder it is not in."""
    copy = tmp_path / "my-cell.yaml"
    copy.write_text((CONFIG / name).read_text())
    cfg = load_cell_config(copy)
    assert cfg.profile.name == load_cell_config(CONFIG / name).profile.name
    for c in cfg.gripper.calibrations:
        assert Path(c).resolve().parent == (CONFIG / "calibrations").resolve()


def test_profiles_and_calibrations_by_name_and_a_local_file_first(tmp_path):
    data = yaml.safe_load((CONFIG / "cell-gripper-modbus-sim.yaml").read_text())
    data["profile"] = "pneunet-gripper-quick"
    data["gripper"]["calibrations"] = ["pneunet-gripper-quick-p_eq"]
    cfg = load_cell_config(write(tmp_path, "cell.yaml", data))
    assert cfg.profile.name == "pneunet-gripper-quick"
    assert Path(cfg.gripper.calibrations[0]).resolve() == (CONFIG / "calibrations" / "pneunet-gripper-quick-p_eq.json").resolve()
    # a file of that name next to the config comes first: it is the user's own
    (tmp_path / "profiles").mkdir()
    mine = yaml.safe_load((CONFIG / "profiles" / "pneunet-gripper-quick.yaml").read_text())
    mine["sequence"]["p0_kpa"] = mine["sequence"]["p0_kpa"] - 1.0
    write(tmp_path / "profiles", "pneunet-gripper-quick.yaml", mine)
    data["profile"] = "profiles/pneunet-gripper-quick.yaml"
    ours = load_cell_config(write(tmp_path, "cell.yaml", data))
    assert ours.profile.sequence.p0_kpa == cfg.profile.sequence.p0_kpa - 1.0
    # a name that is neither says where it looked
    data["profile"] = "no-such-gripper"
    with pytest.raises(ConfigError) as err:
        load_cell_config(write(tmp_path, "cell.yaml", data))
    assert str(err.value).startswith(f"{tmp_path}/cell.yaml: profile: {tmp_path}/no-such-gripper: No such file or "
                                     "directory, and no shipped file of that name in profiles/ (shipped: ")
    assert "pneunet-gripper-quick" in str(err.value)
    # nothing climbs out of the shipped folder by name
    data["profile"] = "../cell-sim.yaml"
    with pytest.raises(ConfigError, match="No such file or directory$"):
        load_cell_config(write(tmp_path, "cell.yaml", data))


def _init(capsys, cwd: Path, *args: str) -> Ran:
    return run_cli(capsys, "init", *args, cwd=cwd)


@pytest.mark.parametrize("driver", ["sim", "ur", "modbus", "serial", "nidaqmx"])
def test_init_writes_a_config_that_loads_from_anywhere(tmp_path, driver, capsys):
    r = _init(capsys, tmp_path, "--driver", driver, "--out", "cell.yaml")
    assert r.returncode == 0, r.stderr
    cfg = load_cell_config(tmp_path / "cell.yaml")
    assert cfg.driver.kind == driver
    assert f"config/cell-" not in (tmp_path / "cell.yaml").read_text()  # its comments name the new file


def test_init_never_overwrites_without_force(tmp_path, capsys):
    mine = write(tmp_path, "cell.yaml", "# my cell, hours of wiring\n")
    r = _init(capsys, tmp_path, "--driver", "ur", "--out", "cell.yaml")
    assert r.returncode == 2 and r.stderr.strip() == "fluidsense: error: --out: cell.yaml exists: pass --force to replace it"
    assert mine.read_text() == "# my cell, hours of wiring\n"
    r = _init(capsys, tmp_path, "--driver", "ur", "--out", "cell.yaml", "--host", "10.0.0.7", "--force")
    assert r.returncode == 0, r.stderr
    assert load_cell_config(mine).driver.host == "10.0.0.7"
    r = _init(capsys, tmp_path, "--driver", "modbus", "--out", "other.yaml", "--profile", "no-such-gripper")
    assert r.returncode == 2 and "other.yaml: profile: " in r.stderr and not (tmp_path / "other.yaml").exists()
    assert not list(tmp_path.glob(".*"))  # no trial file left behind


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
    if section in ("actuator", "circuit"):  # the whole section: only the keys given
        change = whole(change | {"kind": "tank"} if section == "circuit" else change)
    ppath = profile_config(tmp_path, check=False, **{section: change})
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


def test_run_with_a_bad_config_exits_before_binding_or_moving_anything(tmp_path, capsys):
    data = cell(tmp_path, **{"driver.block_size": -1})
    path = write(tmp_path, "bad.yaml", data)
    out = run_cli(capsys, "run", "--config", path, cwd=REPO)  # a bind would fail it here (tests/unit's guard)
    assert out.returncode == 2
    assert f"{path}: driver.block_size: " in out.stderr
    pub_path = data["publisher"]["pub"].removeprefix("ipc://")
    assert not Path(pub_path).exists()  # no socket was ever bound


# ----------------------------------------------------------------- semantic checks at load (issue 14, item 6)
def refused_at(tmp_path: Path, data: dict) -> str:
    path = write(tmp_path, f"cell-{len(list(tmp_path.iterdir()))}.yaml", data)
    with pytest.raises(ConfigError) as err:
        load_cell_config(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: ") and "\n" not in msg, msg
    return msg.removeprefix(f"{path}: ")


@pytest.mark.parametrize("endpoint, shown", [
    ("tcp://127.0.0.1:99999", "'99999'"), ("tcp://127.0.0.1:0", "'0'"), ("tcp://127.0.0.1:*", "'*'"),
    ("tcp://127.0.0.1:55x", "'55x'"), ("tcp://127.0.0.1:", "''"),
])
def test_a_zeromq_port_outside_1_to_65535_is_refused(tmp_path, endpoint, shown):
    """libzmq binds a wildcard or out-of-range port to a random one: no client would find it."""
    for socket_name in ("pub", "cmd"):
        data = cell(tmp_path, **{f"publisher.{socket_name}": endpoint})
        assert refused_at(tmp_path, data) == \
            f"publisher.{socket_name}: '{endpoint}': the port must be a number in 1..65535, got {shown}"
    assert load_cell_config(write(tmp_path, "ok.yaml", cell(tmp_path, **{"publisher.pub": "tcp://127.0.0.1:65535"})))


def test_other_ports_and_one_endpoint_for_both_sockets(tmp_path):
    data = cell(tmp_path)
    data["publisher"]["cmd"] = data["publisher"]["pub"]
    assert refused_at(tmp_path, data) == f"publisher.cmd: '{data['publisher']['cmd']}' is also the pub endpoint: " \
        "each socket needs its own"
    for port in (0, 70000):
        modbus = cell_data(tmp_path, "cell-modbus-sim", driver={"port": port})
        assert refused_at(tmp_path, modbus).startswith("driver.port: Input should be ")


def test_p0_must_stay_a_margin_inside_the_limits(tmp_path):
    """P0 at the limit faulted every cycle (the tank sensor reads P0 plus noise). The
    margin follows from the profile's sensors and regulator (Profile.p0_margin_kpa)."""
    profile = profile_data()
    margin = load_profile(CONFIG / "profiles" / "pneunet-gripper.yaml").p0_margin_kpa
    sensor, tank = profile["sensor"], profile["tank_sensor"]
    assert margin == pytest.approx(max(abs(sensor["offset_kpa"]), abs(tank.get("offset_kpa", 0)))
                                   + max(sensor.get("quantum_kpa", 0.016), tank.get("quantum_kpa", 0.016))
                                   + 4 * profile["circuit"]["regulator_repeatability_kpa"]
                                   + 6 * max(sensor["noise_sd_kpa"], tank["noise_sd_kpa"]))
    top = profile["limits"]["max_kpa"]
    for p0, ok in ((top, False), (top - margin + 0.01, False), (top - margin - 0.01, True)):
        path = profile_config(tmp_path, check=False, sequence={"p0_kpa": p0})
        if ok:
            assert load_profile(path).sequence.p0_kpa == p0
            continue
        with pytest.raises(ConfigError) as err:
            load_profile(path)
        assert str(err.value).startswith(f"{path}: sequence.p0_kpa: {p0} is within {margin:.2f} kPa of limits "
                                         f"[{profile['limits']['min_kpa']}, {top}] kPa: the readings around P0")
    vacuum = profile_config(tmp_path, "suction-cup", check=False,
                            sequence={"p0_kpa": profile_data("suction-cup")["limits"]["min_kpa"] + 0.5})
    with pytest.raises(ConfigError, match=r"sequence.p0_kpa: -79.5 is within 1.06 kPa of limits \[-80.0, 5.0\]"):
        load_profile(vacuum)


@pytest.mark.parametrize("rate, block, reason", [
    (20000, 1, "block_size 1 at 20000 Hz is a block every 0.05 ms: at least 5 ms per block (block_size >= 100) "
               "leaves the loop time to yield"),
    (1000, 10000, "block_size 10000 at 1000 Hz is a block every 10 s: at most 0.1 s (supervision.no_data_s / 5), "
                  "or waiting for a block is a no_data fault"),
])
def test_the_block_period_must_let_the_loop_yield_and_beat_no_data(tmp_path, rate, block, reason):
    data = cell(tmp_path, **{"driver.rate_hz": rate, "driver.block_size": block})
    assert refused_at(tmp_path, data) == f"driver.block_size: {reason}"


def test_block_period_bounds_and_rate(tmp_path):
    """5 ms and no_data_s / 5 are both allowed; a rate below 1 Hz is refused at the rate."""
    for block, no_data in ((5, 0.5), (100, 0.5)):
        data = cell(tmp_path, **{"driver.block_size": block})
        data["supervision"] = {"no_data_s": no_data}
        assert load_cell_config(write(tmp_path, "ok.yaml", data)).driver.block_size == block
    data = cell(tmp_path, **{"driver.block_size": 10})
    data["supervision"] = {"no_data_s": 0.04}
    assert refused_at(tmp_path, data).startswith("driver.block_size: block_size 10 at 1000 Hz is a block every 0.01 s: "
                                                 "at most 0.008 s")
    assert refused_at(tmp_path, cell(tmp_path, **{"driver.rate_hz": 1e-300})) == \
        "driver.rate_hz: Input should be greater than or equal to 1"


@pytest.mark.parametrize("sequence, field", [
    ({"windows": [{"name": "eq", "start_s": 4.0, "end_s": 4.002}]}, "profile.sequence.windows.0"),
    ({"offset_s": 0.003}, "profile.sequence.offset_s"),
])
def test_windows_hold_a_few_samples(tmp_path, sequence, field):
    msg = refused_at(tmp_path, cell_data(tmp_path, sim_config(tmp_path), profile={"sequence": sequence}))
    assert msg.startswith(f"{field}: ") and msg.endswith("samples at 1000 Hz: a mean over fewer than 5 samples is "
                                                         "mostly sensor noise")


def test_files_a_config_names_must_exist(tmp_path):
    missing = tmp_path / "gone.yaml"
    assert refused_at(tmp_path, cell(tmp_path, profile=str(missing))) == \
        f"profile: {missing}: No such file or directory"
    replay = cell(tmp_path)
    replay["driver"] = {"kind": "replay", "file": str(tmp_path / "run.mcap")}
    assert refused_at(tmp_path, replay) == f"driver.file: {tmp_path}/run.mcap: No such file or directory"
    replay["driver"]["file"] = str(tmp_path)
    assert refused_at(tmp_path, replay) == f"driver.file: {tmp_path} is not a regular file (a directory)"
    a_file = write(tmp_path, "a-file", "x")
    rec = cell(tmp_path)
    rec["recording"]["dir"] = str(a_file)
    assert refused_at(tmp_path, rec) == f"recording.dir: {a_file} exists and is not a directory"
    rec["recording"]["dir"] = str(tmp_path / ("x" * 300))
    assert refused_at(tmp_path, rec) == "recording.dir: File name too long"


def test_run_with_a_bad_port_binds_nothing_and_records_nothing(tmp_path, capsys):
    data = cell(tmp_path, **{"publisher.cmd": "tcp://127.0.0.1:99999"})
    path = write(tmp_path, "bad-port.yaml", data)
    out = run_cli(capsys, "run", "--config", path, cwd=tmp_path)
    assert out.returncode == 2
    assert out.stderr.splitlines() == [f"fluidsense: error: {path}: publisher.cmd: 'tcp://127.0.0.1:99999': the port "
                                       "must be a number in 1..65535, got '99999'"]
    assert not Path(data["recording"]["dir"]).exists()
    assert not Path(data["publisher"]["pub"].removeprefix("ipc://")).exists()
