"""Every configuration model refuses bad input with FILE: field: reason (missing field,
wrong type, out of range, unknown field), through the same loader the YAML files use.

(Its in-process tests: tests/unit/test_config_models.py.)
"""

from __future__ import annotations

import importlib
import pytest

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


def test_the_publisher_keeps_queue_s_of_its_message_rate_for_a_slow_subscriber(tmp_path):
    """Not 10,000 messages (15 minutes of the stream, +12.6 MB over an 8-hour soak): queue_s
    of what it sends, a batch per pressure_batch_s, a heartbeat per heartbeat_s, 2 events a
    second (docs/soak.md); the daemon's publisher is bound with it."""
    from fluidsense.controller.config import load_cell_config
    from fluidsense.controller.config.cell import PublisherConfig
    from fluidsense.daemon.app import bind_publisher
    from support.harness import sim_config

    assert PublisherConfig().hwm_messages == 390  # 30 s x (10 + 1 + 2) a second
    assert PublisherConfig(pressure_batch_s=0.5, heartbeat_s=2.0, queue_s=10).hwm_messages == 45
    cfg = load_cell_config(sim_config(tmp_path))
    pub = bind_publisher(cfg)
    try:
        assert pub._hwm == 390  # noqa: SLF001 - what the outlet's XPUB is given
    finally:
        pub.close()
