"""Every configuration model refuses bad input with FILE: field: reason (missing field,
wrong type, out of range, unknown field), through the same loader the YAML files use.

(Its tests with real peers: tests/system/test_config_models.py.)
"""

from __future__ import annotations

import importlib
from pathlib import Path

import annotated_types as at
import pytest
from fluidsense.common.errors import ConfigError
from fluidsense.common.models import StrictModel
from fluidsense.controller.config import validate

MODULES = ["fluidsense.common.hardware", "fluidsense.common.scenes", "fluidsense.common.world", "fluidsense.drivers.registry", "fluidsense.drivers.sampler.config",
           "fluidsense.drivers.reconnect", "fluidsense.drivers.recording.config",
           "fluidsense.drivers.ur.box", "fluidsense.common.wiring", "fluidsense.drivers.ur.config", "fluidsense.drivers.modbus.config", "fluidsense.drivers.serial.config",
           "fluidsense.drivers.daqmx.config",
           "fluidsense.controller.config", "fluidsense.controller.requests.dispatch", "fluidsense.controller.sensing.calibration", "fluidsense.tasks.config"]
for m in MODULES:
    importlib.import_module(m)

# a valid instance for the models that have required fields
EXAMPLES = {
    "Hose": {"bore_mm": 4.3, "length_m": 3.3},  # the paper's sorting line (config/profiles/sorting-gripper.yaml)
    "Window": {"name": "eq", "start_s": 4, "end_s": 5},
    "Limits": {"max_kpa": 90, "min_kpa": -5},
    "Profile": {"name": "p"},
    "CellConfig": {"driver": {"kind": "sim"}, "profile": {"name": "p"}},
    "ReplayDriverConfig": {"file": "run.mcap"},
    "CylinderScene": {"diameter_mm": 60},
    "RectangleScene": {"width_mm": 60},
    "PlateScene": {"height_mm": 10},
    "StopperScene": {"angle_deg": 10},
    "WallScene": {"distance_mm": 10},
    "CalibrationPlan": {"scene": {"kind": "plate", "height_mm": 0}, "target": "height_mm", "values": [0, 10]},
    "CurveKeys": None,  # files that must exist, made by the curve_keys fixture
    "WorldObject": {"name": "o", "diameter_mm": 60},
    "WorldSlot": {"name": "s", "pose": [0, 0, 0, 0, 0, 0]},
    "WorldSpec": {"slots": [{"name": "s", "pose": [0, 0, 0, 0, 0, 0]}]},
    "PollerSpec": {"factory": "fluidsense.drivers.sampler.synthetic:SyntheticPoller"},
    "SamplerConfig": {"poller": {"factory": "fluidsense.drivers.sampler.synthetic:SyntheticPoller"}, "channels": ["p_act"]},
    "StatusRequest": {"cmd": "status"}, "CycleRequest": {"cmd": "cycle"}, "AbortRequest": {"cmd": "abort"},
    "ResetRequest": {"cmd": "reset"}, "SceneRequest": {"cmd": "scene", "scene": {"kind": "none"}},
    "TaskRequest": {"cmd": "task", "file": "x.yaml"}, "ShutdownRequest": {"cmd": "shutdown"},
    "GripRequest": {"cmd": "grip"}, "ReleaseRequest": {"cmd": "release"}, "MeasureRequest": {"cmd": "measure"},
    "RipenessObject": {"name": "o", "diameter_mm": 55},
    "Estimate": {"quantity": "diameter"},
    "FittedNumber": {"field": "actuator.v0_ml", "value": 100.0, "lo95": 90.0, "hi95": 110.0},
    "ContactReading": {"size": 60.0, "cycles": 3, "p_eq_kpa": 35.5, "p_eq_sd_kpa": 0.02},
    "ContactProvenance": {"scene": "cylinder", "target": "diameter_mm", "p0_kpa": 63.0, "cycles_per_target": 3,
                          "free": {"size": None, "cycles": 3, "p_eq_kpa": 33.8, "p_eq_sd_kpa": 0.02},
                          "readings": [{"size": 60.0, "cycles": 3, "p_eq_kpa": 35.5, "p_eq_sd_kpa": 0.02}], "dof": 1},
    "Provenance": {"date": "2026-11-27T23:00:00+00:00", "rig": "driver sim", "config": "cell.yaml",
                   "from_profile": "pneunet-gripper", "levels_kpa": [20, 40, 63], "cycles_per_level": 4,
                   "residual_kpa": 0.01, "pure_error_kpa": 0.04},
    "CalibrationFile": {"format": "fluidsense-calibration/1", "profile": "p", "method": "tank", "feature": "p_eq",
                        "feature_unit": "kPa", "scene": {"kind": "plate"}, "target": "height_mm", "target_unit": "mm",
                        "fit": "linear", "coeffs": [-0.04, 22.6], "x": [0, 10, 20], "y": [22.6, 22.2, 21.8]},
    "Ratiometric": {"range_kpa": [-34.5, 34.5]}, "Mpx": {"a_per_kpa": 0.004, "b": 0.04},
    "Linear": {"range_kpa": [0, 600]}, "ValveWiring": {"output": 0}, "RegulatorWiring": {"analog_output": 0},
    "SensorWiring": {"analog_input": 0, "transfer": {"kind": "linear", "range_kpa": [0, 600]}},
    "Wiring": {"valves": {"actuate": {"output": 1}},
               "sensors": {"p_act": {"analog_input": 0, "transfer": {"kind": "linear", "range_kpa": [0, 600]}}}},
    "UrDriverConfig": {"host": "10.0.0.2", "wiring": {
        "valves": {"actuate": {"output": 1}},
        "sensors": {"p_act": {"analog_input": 0, "transfer": {"kind": "linear", "range_kpa": [0, 600]}}}}},
    "ModbusDriverConfig": {"host": "10.0.0.2", "wiring": {
        "valves": {"actuate": {"output": 1}},
        "sensors": {"p_act": {"analog_input": 0, "transfer": {"kind": "linear", "range_kpa": [0, 600]}}}}},
    "SerialValveWiring": {"output": 1},
    "SerialSensorWiring": {"adc": 0, "transfer": {"kind": "ratiometric", "range_kpa": [-34.5, 34.5]}},
    "SerialWiring": {"valves": {"actuate": {"output": 1}},
                     "sensors": {"p_act": {"adc": 0, "transfer": {"kind": "ratiometric", "range_kpa": [-34.5, 34.5]}}}},
    "SerialDriverConfig": {"port": "/dev/ttyACM0", "wiring": {
        "valves": {"actuate": {"output": 1}},
        "sensors": {"p_act": {"adc": 0, "transfer": {"kind": "ratiometric", "range_kpa": [-34.5, 34.5]}}}}},
    "DaqValveWiring": {"line": 1},
    "DaqRegulatorWiring": {"analog_output": 0},
    "DaqSensorWiring": {"ai": 0, "transfer": {"kind": "ratiometric", "range_kpa": [-34.5, 34.5]}},
    "DaqWiring": {"valves": {"actuate": {"line": 1}},
                  "sensors": {"p_act": {"ai": 0, "transfer": {"kind": "ratiometric", "range_kpa": [-34.5, 34.5]}}}},
    "NiDaqDriverConfig": {"device": "Dev1", "wiring": {
        "valves": {"actuate": {"line": 1}},
        "sensors": {"p_act": {"ai": 0, "transfer": {"kind": "ratiometric", "range_kpa": [-34.5, 34.5]}}}}},
    "SortingTask": {"task": "sorting", "cell": "c.yaml", "slots": {"a": [0, 0, 0, 0, 0, 0], "b": [0, 0, 0, 0, 0, 0]},
                    "input_slots": ["a"], "sorted_slots": ["b"]},
    "PickingTask": {"task": "picking", "cell": "c.yaml", "slots": {"a": [0, 0, 0, 0, 0, 0], "b": [0, 0, 0, 0, 0, 0]},
                    "tomato_slots": ["a"], "place_slots": ["b"]},
    "RipenessTask": {"task": "ripeness", "cell": "c.yaml",
                     "slots": {"a": [0, 0, 0, 0, 0, 0], "b": [0, 0, 0, 0, 0, 0], "c": [0, 0, 0, 0, 0, 0]},
                     "dummy_slots": ["a", "b"], "dummy_diameters_mm": [45, 65], "object_slots": ["c"],
                     "objects": [{"name": "o", "diameter_mm": 55}]},
}


@pytest.fixture(autouse=True, scope="module")
def curve_keys(tmp_path_factory):
    """CurveKeys checks its files at load: a private server key and a client key to let in."""
    import zmq
    from fluidsense.controller.config.curve import write_key_file

    keys = tmp_path_factory.mktemp("curve")
    (keys / "clients").mkdir()
    server, client = zmq.curve_keypair(), zmq.curve_keypair()
    write_key_file(keys / "server.key_secret", *server)
    write_key_file(keys / "clients" / "client.key", client[0])
    EXAMPLES["CurveKeys"] = {"server_secret_file": str(keys / "server.key_secret"),
                             "clients_dir": str(keys / "clients")}


CONFIGURED = tuple(f"fluidsense.{part}." for part in ("common", "drivers", "controller", "tasks"))


def all_models():
    seen, todo = [], list(StrictModel.__subclasses__())
    while todo:
        cls = todo.pop()
        if cls not in seen and cls.__module__.startswith(CONFIGURED) \
                and not cls.__name__.startswith("_"):  # private bases are never configured alone
            seen.append(cls)
        todo.extend(cls.__subclasses__())
    return sorted(seen, key=lambda c: c.__name__)


MODELS = all_models()
PATH = Path("config/example.yaml")


def test_every_model_is_covered():
    names = {m.__name__ for m in MODELS}
    assert len(MODELS) >= 40
    assert {"CellConfig", "Profile", "SequenceConfig", "TankCircuit", "GripperActuator", "SortingTask"} <= names


def example(model) -> dict:
    data = dict(EXAMPLES.get(model.__name__, {}))
    validate(model, data, PATH)  # the example itself is valid
    return data


def _bound(field):
    for meta in field.metadata:
        if isinstance(meta, (at.Gt, at.Ge)):
            return "low", meta.gt if isinstance(meta, at.Gt) else meta.ge
        if isinstance(meta, (at.Lt, at.Le)):
            return "high", meta.lt if isinstance(meta, at.Lt) else meta.le
    return None


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.__name__)
def test_unknown_field(model):
    data = {**example(model), "colour_mm": 3}
    with pytest.raises(ConfigError, match=rf"^{PATH}: colour_mm: unknown field"):
        validate(model, data, PATH)


# one case per (model, field): a model with no required or no numeric field adds no case
# that would assert nothing
REQUIRED = [(m, n) for m in MODELS for n, f in m.model_fields.items() if f.is_required()]
NUMERIC = [(m, n, f) for m in MODELS for n, f in m.model_fields.items()
           if f.annotation in (float, int, float | None, int | None)]
BOUNDED = [(m, n, _bound(f)) for m, n, f in NUMERIC if _bound(f) is not None]


def _ids(case) -> str:
    return f"{case[0].__name__}.{case[1]}"


def test_the_cases_cover_the_models():
    assert len(REQUIRED) >= 70 and len(NUMERIC) >= 150 and len(BOUNDED) >= 150  # counted on this commit


@pytest.mark.parametrize("case", REQUIRED, ids=_ids)
def test_missing_required_field(case):
    model, name = case
    data = {k: v for k, v in example(model).items() if k != name}
    with pytest.raises(ConfigError, match=rf"{PATH}: {name}: required field is missing"):
        validate(model, data, PATH)


@pytest.mark.parametrize("case", NUMERIC, ids=_ids)
def test_wrong_type(case):
    model, name, _ = case
    with pytest.raises(ConfigError, match=rf"{PATH}: {name}: .*valid (number|integer)"):
        validate(model, {**example(model), name: "lots"}, PATH)


@pytest.mark.parametrize("case", BOUNDED, ids=_ids)
def test_out_of_range(case):
    model, name, (side, edge) = case
    bad = edge - 10**6 if side == "low" else edge + 10**6  # an int for an int field (strict)
    with pytest.raises(ConfigError, match=rf"{PATH}: {name}: .*(greater|less) than"):
        validate(model, {**example(model), name: bad}, PATH)
