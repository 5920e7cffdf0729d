"""Configuration: pydantic models loaded from YAML.

A bad file fails before anything starts, with one line per problem in the form
``FILE: field.path: reason``. Profiles may live in their own file (``profile: PATH``,
relative to the file that names it); their errors then name the profile file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal, TypeVar

import yaml
from pydantic import BaseModel, Field, ValidationError, ValidationInfo, field_validator, model_validator

from drivers.config import DriverConfig
from drivers.errors import ConfigError
from drivers.hardware import Actuator, Circuit, FlowSensor, GripperActuator, Hardware, Sensor, TankCircuit
from drivers.models import StrictModel
from drivers.scenes import Scene
from drivers.units import KPA

from .curve import ALLOW_ANY, count_public_keys, read_secret_key

M = TypeVar("M", bound=BaseModel)


class Window(StrictModel):
    """A measurement window, in seconds after the actuation valve opens."""

    name: str = Field(min_length=1, max_length=40)
    start_s: float = Field(ge=0)
    end_s: float = Field(gt=0)

    @model_validator(mode="after")
    def _ordered(self) -> Window:
        if not self.end_s > self.start_s:
            raise ValueError(f"end_s ({self.end_s}) must be after start_s ({self.start_s})")
        return self


class FlowProfile(StrictModel):
    """Flow-control programme (paper, Methods "Flow control with pressure measurement"):
    ramp from 0 to ``flow_slpm`` in ``ramp_s``, hold ``hold_s``, then zero."""

    flow_slpm: float = Field(0.3, gt=0, le=100)
    ramp_s: float = Field(5.0, ge=0, le=600)
    hold_s: float = Field(4.0, ge=0, le=600)


class SequenceConfig(StrictModel):
    """One actuation cycle: CHARGE -> ISOLATE -> ACTUATE -> HOLD -> VENT.

    Methods (paper, Methods "Distance sensing"): ``tank`` charges a tank to P0 and measures
    the pressure the actuator settles at (method 1; with a free-air reference it also gives
    the pressure-time features of method 4); ``pressure_flow`` holds the actuator at a
    regulated P0 and integrates the flow into it (method 2); ``flow_control`` feeds a flow
    profile and measures the pressure (method 3). A zero-length ISOLATE is skipped.
    """

    method: Literal["tank", "pressure_flow", "flow_control"] = "tank"
    p0_kpa: float = Field(63.0, ge=-100, le=1000,
                          description="tank charge pressure (tank) or regulated pressure (pressure_flow)")
    charge_s: float = Field(10.0, gt=0, le=600)
    isolate_s: float = Field(10.0, ge=0, le=600)
    actuate_s: float = Field(20.0, gt=0, le=3600)
    vent_s: float = Field(10.0, gt=0, le=600)
    offset_s: float = Field(1.0, gt=0, le=60, description="sensor offset: mean of this long before opening")
    windows: list[Window] = Field(default_factory=lambda: [Window(name="eq", start_s=4.0, end_s=5.0)],
                                  min_length=1, max_length=16)
    flow_window: Window | None = Field(
        None, description="integrate the flow into the actuator over this window (pressure_flow: V_eq)")
    flow_profile: FlowProfile | None = Field(None, description="flow_control: the flow programme")
    isolate_actuator_at_s: float | None = Field(
        None, gt=0, description="close the actuation valve this long after opening and hold the actuator "
        "isolated until VENT (needs a circuit with a separate vent valve)")
    contact_threshold_kpa: float = Field(0.5, gt=0, le=100, description="dP level for t_c by threshold")
    onset_kpa: float = Field(0.15, gt=0, le=100, description="dP level taken as the first rise (t_c at onset): "
                             "about five times the noise of a smoothed dP")
    smoothing_samples: int = Field(21, ge=3, le=1001, description="local quadratic regression span")

    @model_validator(mode="after")
    def _consistent(self) -> SequenceConfig:
        if self.offset_s > self.charge_s + self.isolate_s:
            raise ValueError(f"offset_s ({self.offset_s}) must fit before the valve opens "
                             f"(charge_s + isolate_s = {self.charge_s + self.isolate_s})")
        for w in [*self.windows, *([self.flow_window] if self.flow_window else [])]:
            if w.end_s > self.actuate_s:
                raise ValueError(f"window {w.name!r} ends at {w.end_s} s, after the valve closes "
                                 f"(actuate_s = {self.actuate_s})")
        names = [w.name for w in self.windows]
        if len(set(names)) != len(names):
            raise ValueError(f"window names must be unique, got {names}")
        if self.method == "flow_control" and self.flow_profile is None:
            raise ValueError("method flow_control needs a flow_profile")
        if self.method == "pressure_flow" and self.flow_window is None:
            raise ValueError("method pressure_flow needs a flow_window to integrate over")
        if self.method == "tank" and self.isolate_s == 0:
            raise ValueError("method tank needs isolate_s > 0 (the tank must be isolated before opening)")
        if self.isolate_actuator_at_s is not None and self.isolate_actuator_at_s >= self.actuate_s:
            raise ValueError("isolate_actuator_at_s must come before the end of actuate_s")
        return self

    @property
    def p0_pa(self) -> float:
        return self.p0_kpa * KPA


class Limits(StrictModel):
    """Pressure envelope of the actuator (gauge). Nothing may command beyond it."""

    max_kpa: float = Field(gt=-100, le=1000)
    min_kpa: float = Field(ge=-101, le=1000)

    @model_validator(mode="after")
    def _ordered(self) -> Limits:
        if not self.min_kpa < self.max_kpa:
            raise ValueError(f"min_kpa ({self.min_kpa}) must be below max_kpa ({self.max_kpa})")
        return self

    @property
    def max_pa(self) -> float:
        return self.max_kpa * KPA

    @property
    def min_pa(self) -> float:
        return self.min_kpa * KPA


class CalibrationPlan(StrictModel):
    """How this profile is calibrated by default (the paper's protocol for it)."""

    scene: Scene = Field(description="scene whose target field is varied")
    target: str = Field(min_length=1, description="the scene field that is the sensing target")
    values: list[float] = Field(min_length=2, max_length=200)
    cycles: int = Field(8, ge=1, le=1000)
    drop_first: int = Field(1, ge=0, le=100)
    feature: Literal["p_eq", "v_eq", "dp_eq", "dp_max", "t_c_slope", "t_c_threshold", "t_c2"] = "p_eq"
    fit: Literal["linear", "poly2", "poly3"] = "linear"

    @model_validator(mode="after")
    def _target_exists(self) -> CalibrationPlan:
        if self.target not in type(self.scene).model_fields:
            raise ValueError(f"target {self.target!r} is not a field of scene {self.scene.kind!r}")
        if self.drop_first >= self.cycles:
            raise ValueError(f"drop_first ({self.drop_first}) leaves no cycle of {self.cycles}")
        return self


class Profile(StrictModel):
    """One actuator or gripper: its hardware, its safe envelope and its cycle."""

    name: str = Field(min_length=1, max_length=80)
    description: str = ""
    circuit: Circuit = TankCircuit()
    actuator: Actuator = GripperActuator()
    sensor: Sensor = Sensor()
    tank_sensor: Sensor = Sensor(offset_kpa=0.0)
    flow_sensor: FlowSensor = FlowSensor()
    limits: Limits = Limits(max_kpa=90.0, min_kpa=-5.0)
    sequence: SequenceConfig = SequenceConfig()
    calibration: CalibrationPlan | None = None

    @model_validator(mode="after")
    def _consistent(self) -> Profile:
        seq, circuit = self.sequence, self.circuit
        p0 = seq.p0_kpa
        if seq.method != "flow_control" and not self.limits.min_kpa <= p0 <= self.limits.max_kpa:
            raise ValueError(f"sequence.p0_kpa ({p0}) is outside limits "
                             f"[{self.limits.min_kpa}, {self.limits.max_kpa}] kPa")
        needs = {"tank": "tank", "pressure_flow": "regulated", "flow_control": "flow"}[seq.method]
        if circuit.kind != needs:
            raise ValueError(f"sequence.method {seq.method!r} needs circuit.kind {needs!r}, got {circuit.kind!r}")
        if seq.flow_window is not None and not circuit.flow_sensor:
            raise ValueError("sequence.flow_window needs a circuit with flow_sensor: true")
        if seq.isolate_actuator_at_s is not None and not getattr(circuit, "vent_valve", False):
            raise ValueError("sequence.isolate_actuator_at_s needs circuit.vent_valve: true")
        return self

    @property
    def hardware(self) -> Hardware:
        return Hardware(circuit=self.circuit, actuator=self.actuator, sensor=self.sensor,
                        tank_sensor=self.tank_sensor, flow_sensor=self.flow_sensor)


class Supervision(StrictModel):
    """Thresholds of the safety supervisor (controller/supervisor.py)."""

    stuck_s: float = Field(0.25, gt=0, le=60, description="a pressure reading that does not change for this long is stuck")
    leak_kpa_per_s: float = Field(0.1, gt=0, le=100, description="decay towards atmosphere while held that is a leak")
    no_data_s: float = Field(0.5, gt=0, le=60, description="real time: no block for this long is a fault")
    overrun_s: float = Field(0.25, gt=0, le=60, description="real time: the loop this far behind the samples is a fault")


class CurveKeys(StrictModel):
    """ZeroMQ CURVE for the command socket: the server's secret key file and a directory
    of the public keys of the clients allowed in (``fluidsense keys`` makes both). Both are
    checked at load: a key file others can read, or no client key to let in, would give a
    daemon anyone or no one can command. Paths are relative to the working directory."""

    server_secret_file: str = Field(min_length=1, max_length=4096)
    allow_any_client: bool = Field(False, description="let any client key in (clients_dir must then be '*'): "
                                   "traffic is encrypted but not authenticated")
    clients_dir: str = Field(min_length=1, max_length=4096,
                             description="directory of the allowed clients' public keys (*.key)")

    @field_validator("server_secret_file")
    @classmethod
    def _private_key(cls, value: str) -> str:
        read_secret_key(value)
        return value

    @field_validator("clients_dir")
    @classmethod
    def _known_clients(cls, value: str, info: ValidationInfo) -> str:
        any_client = info.data.get("allow_any_client", False)
        if value == ALLOW_ANY or any_client:
            if not (value == ALLOW_ANY and any_client):
                raise ValueError("'*' (any client key) and allow_any_client: true go together; "
                                 "without them, name the directory of the allowed clients' public keys")
            return value
        if count_public_keys(value) == 0:
            raise ValueError(f"{value}: holds no client public key (*.key): nobody could send a command")
        return value


def _is_local(endpoint: str) -> bool:
    if endpoint.startswith(("ipc://", "inproc://")):
        return True
    host = endpoint.removeprefix("tcp://").rsplit(":", 1)[0]
    return host in ("127.0.0.1", "localhost", "[::1]") or host.startswith("127.")


class PublisherConfig(StrictModel):
    """ZeroMQ endpoints. The command socket stays on loopback unless CURVE keys are
    configured: whoever can reach it can move the gripper."""

    pub: str = Field("tcp://127.0.0.1:5560", min_length=6, pattern=r"^(tcp|ipc|inproc)://")
    cmd: str = Field("tcp://127.0.0.1:5561", min_length=6, pattern=r"^(tcp|ipc|inproc)://")
    cmd_curve: CurveKeys | None = None
    pressure_batch_s: float = Field(0.1, gt=0, le=10, description="pressure samples are sent in batches this long")
    heartbeat_s: float = Field(1.0, gt=0, le=60)

    @model_validator(mode="after")
    def _remote_needs_keys(self) -> PublisherConfig:
        if not _is_local(self.cmd) and self.cmd_curve is None:
            raise ValueError(f"cmd {self.cmd!r} is not loopback: a command socket reachable from the network "
                             "needs cmd_curve keys (fluidsense keys makes them)")
        return self


class RecordingConfig(StrictModel):
    """What the daemon writes to disk (docs/recording.md): every sample block and event,
    and the config, in MCAP files named by their start time in ``dir``."""

    enabled: bool = Field(True, description="the daemon records (fluidsense run --no-record turns it off)")
    dir: str = Field("runs", min_length=1, description="directory of the recordings, relative to the "
                     "daemon's working directory; created if missing")
    flush_s: float = Field(1.0, gt=0, le=10, description="sample time between flushes: a killed daemon "
                           "loses at most this much")
    fsync: bool = Field(True, description="also force each flush to storage (power loss), off the sample loop")
    compression: Literal["zstd", "lz4", "none"] = "zstd"
    max_file_mb: float = Field(1024.0, gt=0, le=1_000_000, description="start a new file, between cycles, "
                               "once a file is this large")
    max_file_s: float = Field(3600.0, gt=0, le=7 * 86400, description="start a new file, between cycles, "
                              "once a file covers this much sample time (the writer's index of a file stays "
                              "in memory until the file is closed: ~1 KB per flush)")
    min_free_mb: float = Field(1024.0, ge=0, le=1_000_000, description="stop recording (and say so) when the "
                               "disk has less free space than this")


class CellConfig(StrictModel):
    """A whole cell: which driver, which actuator profile, where to publish."""

    driver: DriverConfig
    profile: Profile
    publisher: PublisherConfig = PublisherConfig()
    supervision: Supervision = Supervision()
    recording: RecordingConfig = RecordingConfig()
    log_level: Literal["DEBUG", "INFO", "WARNING", "ERROR"] = "INFO"

    @model_validator(mode="after")
    def _wired_to_the_profile(self) -> CellConfig:
        wiring = getattr(self.driver, "wiring", None)
        if wiring is None:
            return self
        hw = self.profile.hardware
        problems = wiring.check_against(list(hw.circuit.safe_valves), hw.channels,
                                        regulated=hw.circuit.kind in ("tank", "regulated"))
        if hw.circuit.kind == "flow":
            problems.append("a flow-controlled circuit cannot be driven through control-box I/O (no mass flow "
                            "controller interface): use a tank or regulated circuit")
        if problems:
            raise ValueError("driver.wiring: " + "; ".join(problems))
        return self


# ---------------------------------------------------------------------- loading
def _field_path(loc: tuple, data: Any) -> str:
    """Dotted field path of an error location, without the union tags pydantic inserts
    (``driver.sim.rate_hz`` -> ``driver.rate_hz``): the path the user wrote."""
    parts, node = [], data
    for item in loc:
        if isinstance(node, dict) and item not in node and item in (node.get("kind"), node.get("task")):
            continue  # the tag of a discriminated union, not a key in the file
        if isinstance(item, str) and item.startswith("function-"):
            continue
        parts.append(str(item))
        if isinstance(node, dict):
            node = node.get(item)
        elif isinstance(node, list) and isinstance(item, int) and 0 <= item < len(node):
            node = node[item]
        else:
            node = None
    return ".".join(parts)


def _format_errors(path: Path, exc: ValidationError, data: Any, prefix: str = "") -> str:
    lines = []
    for err in exc.errors():
        loc = _field_path(err["loc"], data)
        loc = f"{prefix}{loc}" if loc else (prefix.rstrip(".") or "(top level)")
        msg = err["msg"].removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            msg = "unknown field (not allowed here)"
        elif err["type"] == "missing":
            msg = "required field is missing"
        lines.append(f"{path}: {loc}: {msg}")
    return "\n".join(lines)


def read_yaml(path: str | Path) -> Any:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f":{mark.line + 1}:{mark.column + 1}" if mark else ""
        reason = getattr(exc, "problem", None) or str(exc)
        raise ConfigError(f"{path}{where}: YAML syntax: {reason}") from exc


def validate(model: type[M], data: Any, path: str | Path, prefix: str = "") -> M:
    """Validate ``data`` read from ``path``; errors become ConfigError naming file and field."""
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: {prefix.rstrip('.') or '(top level)'}: expected a mapping, "
                          f"got {type(data).__name__}")
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_format_errors(Path(path), exc, data, prefix)) from exc


def load_model(model: type[M], path: str | Path) -> M:
    return validate(model, read_yaml(path), path)


def load_profile(path: str | Path) -> Profile:
    return load_model(Profile, path)


def load_cell_config(path: str | Path, overrides: dict[str, Any] | None = None) -> CellConfig:
    """Load a cell config. ``overrides`` replace top-level sections' keys, e.g.
    ``{"driver": {"clock": "virtual"}}`` (used by the demo and tests)."""
    path = Path(path)
    data = read_yaml(path)
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: (top level): expected a mapping, got {type(data).__name__}")
    profile = data.get("profile")
    if isinstance(profile, str):
        profile_path = (path.parent / profile).resolve()
        data = {**data, "profile": load_profile(profile_path)}
    elif isinstance(profile, dict):
        data = {**data, "profile": validate(Profile, profile, path, prefix="profile.")}
    for section, values in (overrides or {}).items():
        current = data.get(section, {})
        if isinstance(current, BaseModel):
            current = current.model_dump()
        data = {**data, section: {**(current or {}), **values}}
    return validate(CellConfig, data, path)
