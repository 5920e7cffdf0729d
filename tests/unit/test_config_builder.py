"""The tests' config builder (support/configs.py): what the other tests rely on it for."""

from __future__ import annotations

import pytest
from fluidsense.common.errors import ConfigError
from fluidsense.controller.config import load_cell_config, load_profile
from fluidsense.tasks.config import load_task
from support.configs import CONFIG, DELETE, cell_config, profile_config, read, task_config, whole


@pytest.mark.parametrize("base", sorted(p.stem for p in CONFIG.glob("cell-*.yaml")))
def test_every_shipped_cell_config_builds_into_the_tests_directory_and_loads(tmp_path, base):
    path = cell_config(tmp_path, base)
    data = read(path)
    assert path.parent == tmp_path and data["recording"]["dir"] == str(tmp_path / "runs")
    assert all(data["publisher"][s].startswith(f"ipc://{tmp_path}/") for s in ("pub", "cmd"))
    if base != "cell-nidaqmx":  # its driver needs NI's library to load; the models checked it above
        assert load_cell_config(path).profile.name == load_cell_config(CONFIG / f"{base}.yaml").profile.name


@pytest.mark.parametrize("overrides, field", [
    ({"supervison": {"no_data_s": 5}}, "supervison: unknown field"),
    ({"supervision": {"no_data": 5}}, "supervision.no_data: unknown field"),
    ({"driver": {"rate_hz": "fast"}}, "driver.rate_hz: Input should be a valid number"),
    ({"profile": {"sequence": {"charge": 0.5}}}, "profile.sequence.charge: unknown field"),
])
def test_a_typo_in_an_override_fails_at_once_naming_the_field(tmp_path, overrides, field):
    with pytest.raises(ConfigError) as err:
        cell_config(tmp_path, "cell-ur-sim", **overrides)
    assert field in str(err.value), err.value


def test_overrides_merge_delete_and_replace(tmp_path):
    path = cell_config(tmp_path, "cell-modbus-sim", supervision={"no_data_s": 5.0},
                       driver={"sim_control_port": DELETE, "arm": None,
                               "wiring": {"sensors": {"p_act": {"transfer": {"range_kpa": [-50, 50]}}}}})
    driver = read(path)["driver"]
    shipped = read(CONFIG / "cell-modbus-sim.yaml")["driver"]
    assert "sim_control_port" not in driver and driver["arm"] is None and driver["port"] == shipped["port"]
    p_act = shipped["wiring"]["sensors"]["p_act"]
    assert driver["wiring"]["sensors"]["p_act"] == {**p_act, "transfer": {**p_act["transfer"], "range_kpa": [-50, 50]}}
    assert load_cell_config(path).supervision.no_data_s == 5.0
    transfer = whole({"kind": "linear", "range_kpa": [-50, 50]})  # no supply_v: a linear sensor has none
    replaced = read(cell_config(tmp_path, path, driver={"wiring": {"sensors": {"p_act": {"transfer": transfer}}}}))
    assert replaced["driver"]["wiring"]["sensors"]["p_act"]["transfer"] == dict(transfer)


def test_profiles_and_task_files_too_and_a_deliberately_bad_one_is_written_unchecked(tmp_path):
    assert load_profile(profile_config(tmp_path, "sorting-gripper", sequence={"charge_s": 0.5})).sequence.charge_s == 0.5
    with pytest.raises(ConfigError, match=r"sequence.p0_kpa: "):
        profile_config(tmp_path, sequence={"p0_kpa": 1e6})
    bad = profile_config(tmp_path, sequence={"p0_kpa": 1e6}, check=False)
    with pytest.raises(ConfigError, match=rf"^{bad}: sequence.p0_kpa: "):
        load_profile(bad)
    task = task_config(tmp_path, "sorting", motion={"speed_m_s": 1.0})
    assert load_task(task).motion.speed_m_s == 1.0 and load_task(task).motion.acc_m_s2 == 1.2
    with pytest.raises(ConfigError, match=r"motion.speed_m_s: "):
        task_config(tmp_path, "sorting", motion={"speed_m_s": 7})
