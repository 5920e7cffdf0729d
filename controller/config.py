"""Configuration: pydantic models loaded from YAML.

A bad file fails before anything starts, with one line per problem in the form
``FILE: field.path: reason``. Profiles may live in their own file (``profile: PATH``,
relative to the file that names it); their errors then name the profile file.
"""

from __future__ import annotations

import math
import os
import stat
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, Field, ValidationInfo, field_validator, model_validator

from drivers.config import DriverConfig
from drivers.errors import ConfigError
from drivers.files import one_line
from drivers.hardware import Actuator, Circuit, FlowSensor, GripperActuator, Hardware, Sensor, TankCircuit
from drivers.models import FieldError, Integer, Real, StrictModel
from drivers.scenes import Scene
from drivers.units import KPA

from .curve import ALLOW_ANY, count_public_keys, read_secret_key
from .loading import load_model, read_yaml, referenced_file, validate

__all__ = ["CellConfig", "Profile", "SequenceConfig", "load_cell_config", "load_model", "load_profile", "read_yaml",
           "validate"]


class Window(StrictModel):
    """A measurement window, in seconds after the actuation valve opens."""

    name: str = Field(min_length=1, max_length=40)
    start_s: Real = Field(ge=0)
    end_s: Real = Field(gt=0)

    @model_validator(mode="after")
    def _ordered(self) -> Window:
        if not self.end_s > self.start_s:
            raise ValueError(f"end_s ({self.end_s}) must be after start_s ({self.start_s})")
        return self


class FlowProfile(StrictModel):
    """Flow-control programme (paper, Methods "Flow control with pressure measurement"):
    ramp from 0 to ``flow_slpm`` in ``ramp_s``, hold ``hold_s``, then zero."""

    flow_slpm: Real = Field(0.3, gt=0, le=100)
    ramp_s: Real = Field(5.0, ge=0, le=600)
    hold_s: Real = Field(4.0, ge=0, le=600)


class SequenceConfig(StrictModel):
    """One actuation cycle: CHARGE -> ISOLATE -> ACTUATE -> HOLD -> VENT.

    Methods (paper, Methods "Distance sensing"): ``tank`` charges a tank to P0 and measures
    the pressure the actuator settles at (method 1; with a free-air reference it also gives
    the pressure-time features of method 4); ``pressure_flow`` holds the actuator at a
    regulated P0 and integrates the flow into it (method 2); ``flow_control`` feeds a flow
    profile and measures the pressure (method 3). A zero-length ISOLATE is skipped.
    """

    method: Literal["tank", "pressure_flow", "flow_control"] = "tank"
    p0_kpa: Real = Field(63.0, ge=-100, le=1000,
                          description="tank charge pressure (tank) or regulated pressure (pressure_flow)")
    charge_s: Real = Field(10.0, gt=0, le=600)
    isolate_s: Real = Field(10.0, ge=0, le=600)
    actuate_s: Real = Field(20.0, gt=0, le=3600)
    vent_s: Real = Field(10.0, gt=0, le=600)
    offset_s: Real = Field(1.0, gt=0, le=60, description="sensor offset: mean of this long before opening")
    windows: list[Window] = Field(default_factory=lambda: [Window(name="eq", start_s=4.0, end_s=5.0)],
                                  min_length=1, max_length=16)
    flow_window: Window | None = Field(
        None, description="integrate the flow into the actuator over this window (pressure_flow: V_eq)")
    flow_profile: FlowProfile | None = Field(None, description="flow_control: the flow programme")
    isolate_actuator_at_s: Real | None = Field(
        None, gt=0, description="close the actuation valve this long after opening and hold the actuator "
        "isolated until VENT (needs a circuit with a separate vent valve)")
    contact_threshold_kpa: Real = Field(0.5, gt=0, le=100, description="dP level for t_c by threshold")
    onset_kpa: Real = Field(0.15, gt=0, le=100, description="dP level taken as the first rise (t_c at onset): "
                             "about five times the noise of a smoothed dP")
    smoothing_samples: Integer = Field(21, ge=3, le=1001, description="local quadratic regression span")

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

    max_kpa: Real = Field(gt=-100, le=1000)
    min_kpa: Real = Field(ge=-101, le=1000)

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
    values: list[Real] = Field(min_length=2, max_length=200)
    cycles: Integer = Field(8, ge=1, le=1000)
    drop_first: Integer = Field(1, ge=0, le=100)
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
        if seq.method != "flow_control":
            lo, hi, margin = self.limits.min_kpa, self.limits.max_kpa, self.p0_margin_kpa
            if not lo <= p0 <= hi:
                raise FieldError("sequence.p0_kpa", f"{p0} is outside limits [{lo}, {hi}] kPa")
            if not lo + margin <= p0 <= hi - margin:
                raise FieldError("sequence.p0_kpa", f"{p0} is within {margin:.2f} kPa of limits [{lo}, {hi}] kPa: "
                                 "the readings around P0 would cross the limit and fault the cycle (sensor offset, "
                                 "noise and regulator repeatability); lower P0 or widen the limits")
        needs = {"tank": "tank", "pressure_flow": "regulated", "flow_control": "flow"}[seq.method]
        if circuit.kind != needs:
            raise ValueError(f"sequence.method {seq.method!r} needs circuit.kind {needs!r}, got {circuit.kind!r}")
        if seq.flow_window is not None and not circuit.flow_sensor:
            raise ValueError("sequence.flow_window needs a circuit with flow_sensor: true")
        if seq.isolate_actuator_at_s is not None and not getattr(circuit, "vent_valve", False):
            raise ValueError("sequence.isolate_actuator_at_s needs circuit.vent_valve: true")
        return self

    @property
    def p0_margin_kpa(self) -> float:
        """How far inside the limits P0 must stay. The supervisor compares every raw reading
        of every pressure channel with the limits; the tank sensor reads P0 for the whole
        charge (charge_s + isolate_s: 2e4 samples per cycle at 1 kHz with the defaults),
        and the actuator sensor gets there with the regulated methods. A reading is P0 +
        the regulator's error for this charge (sd ``regulator_repeatability_kpa``, once
        per cycle) + the sensor's offset + noise (sd ``noise_sd_kpa``, every sample) +
        up to one quantum. The margin takes 4 sd of the regulator (beyond it: 3e-5 of
        cycles) and 6 sd of the noise (2e4 samples x 1e-9 each: 2e-5 of cycles), plus the
        largest |offset| and quantum. With the default sensors that is about 1.1 kPa. On
        the simulated gripper at P0 = 63 kPa (offset 0 on the tank sensor) a limit 0.25 kPa
        above P0 faulted 26 of 40 cycles, 0.5 kPa 1 of 400, 0.75 kPa none of 400. Real
        regulators may overshoot a step: give their datasheet's repeatability (or more)
        in the circuit so the margin covers it."""
        sensors = [self.sensor, *([self.tank_sensor] if self.circuit.has_tank_sensor else [])]
        regulator_sd = getattr(self.circuit, "regulator_repeatability_kpa", 0.0)
        return (max(abs(s.offset_kpa) for s in sensors) + max(s.quantum_kpa for s in sensors)
                + 4.0 * regulator_sd + 6.0 * max(s.noise_sd_kpa for s in sensors))

    @property
    def hardware(self) -> Hardware:
        return Hardware(circuit=self.circuit, actuator=self.actuator, sensor=self.sensor,
                        tank_sensor=self.tank_sensor, flow_sensor=self.flow_sensor)


class Supervision(StrictModel):
    """Thresholds of the safety supervisor (controller/supervisor.py)."""

    stuck_s: Real = Field(0.25, gt=0, le=60, description="a pressure reading that does not change for this long is stuck")
    leak_kpa_per_s: Real = Field(0.1, gt=0, le=100, description="decay towards atmosphere while held that is a leak")
    no_data_s: Real = Field(0.5, gt=0, le=60, description="real time: no block for this long is a fault")
    overrun_s: Real = Field(0.25, gt=0, le=60, description="real time: the loop this far behind the samples is a fault")


class LoopConfig(StrictModel):
    """Scheduling of the daemon's event loop (real time only)."""

    rt_priority: Annotated[Integer, Field(ge=1, le=99)] | None = Field(
        20, description="SCHED_FIFO priority of the sample loop's thread when permitted (null: normal "
        "scheduling). Below the sampler process (40) and fluidsense simcell (30), above every normal process: "
        "beside two busy processes at normal priority, a daemon at normal priority fell 0.25 s behind its "
        "samples and faulted mid-task (docs/performance.md)")


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
    pressure_batch_s: Real = Field(0.1, gt=0, le=10, description="pressure samples are sent in batches this long")
    heartbeat_s: Real = Field(1.0, gt=0, le=60)

    @field_validator("pub", "cmd")
    @classmethod
    def _endpoint(cls, endpoint: str) -> str:
        scheme, _, rest = endpoint.partition("://")
        if scheme == "tcp":
            host, colon, port = rest.rpartition(":")
            if not colon or not host:
                raise ValueError(f"{endpoint!r}: expected tcp://HOST:PORT")
            # libzmq binds a wildcard port ("*", 0) or one past 65535 to a random port, where
            # no client configured with this file would ever find the daemon
            if not (port.isascii() and port.isdigit() and 1 <= int(port) <= 65535):
                raise ValueError(f"{endpoint!r}: the port must be a number in 1..65535, got {port!r}")
        elif not rest:
            raise ValueError(f"{endpoint!r}: no address after {scheme}://")
        return endpoint

    @model_validator(mode="after")
    def _distinct(self) -> PublisherConfig:
        if self.pub == self.cmd:
            raise FieldError("cmd", f"{self.cmd!r} is also the pub endpoint: each socket needs its own")
        return self

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
    flush_s: Real = Field(1.0, gt=0, le=10, description="sample time between flushes: a killed daemon "
                           "loses at most this much")
    fsync: bool = Field(True, description="also force each flush to storage (power loss), off the sample loop")
    compression: Literal["zstd", "lz4", "none"] = "zstd"
    max_file_mb: Real = Field(1024.0, gt=0, le=1_000_000, description="start a new file, between cycles, "
                               "once a file is this large")
    max_file_s: Real = Field(3600.0, gt=0, le=7 * 86400, description="start a new file, between cycles, "
                              "once a file covers this much sample time (the writer's index of a file stays "
                              "in memory until the file is closed: ~1 KB per flush)")
    min_free_mb: Real = Field(1024.0, ge=0, le=1_000_000, description="stop recording (and say so) when the "
                               "disk has less free space than this")


# The sample loop's pacing (CellConfig._paced): a block at most every 5 ms (200 loop
# iterations a second, each handling a block, feeding the sinks and publishing) leaves
# the event loop time to serve commands and signals; at least NO_DATA_BLOCKS blocks per
# no_data_s lets a block arrive a few periods late before the wait for it is a fault.
MIN_BLOCK_PERIOD_S = 0.005
NO_DATA_BLOCKS = 5
MIN_WINDOW_SAMPLES = 5


class CellConfig(StrictModel):
    """A whole cell: which driver, which actuator profile, where to publish."""

    driver: DriverConfig
    profile: Profile
    publisher: PublisherConfig = PublisherConfig()
    supervision: Supervision = Supervision()
    recording: RecordingConfig = RecordingConfig()
    loop: LoopConfig = LoopConfig()
    log_level: Literal["DEBUG", "INFO", "WARNING", "ERROR"] = "INFO"

    @model_validator(mode="after")
    def _paced(self) -> CellConfig:
        """The sample loop handles one block per iteration and yields to the event loop
        (commands, publisher, signals) only between blocks. A block every ``block_size /
        rate_hz`` seconds must leave it time to do so: below MIN_BLOCK_PERIOD_S (20 kHz in
        blocks of 1 was accepted once) the loop never catches up and starves everything
        else. It must also come well inside ``supervision.no_data_s``, or every wait for a
        block is a ``no_data`` fault (10000 samples at 1 kHz: a block every 10 s)."""
        rate, block = getattr(self.driver, "rate_hz", None), getattr(self.driver, "block_size", None)
        if rate is None or block is None:
            return self
        period = block / rate
        longest = self.supervision.no_data_s / NO_DATA_BLOCKS
        if period < MIN_BLOCK_PERIOD_S:
            raise FieldError("driver.block_size", f"block_size {block} at {rate:g} Hz is a block every "
                             f"{period * 1e3:.3g} ms: at least {MIN_BLOCK_PERIOD_S * 1e3:g} ms per block "
                             f"(block_size >= {math.ceil(MIN_BLOCK_PERIOD_S * rate)}) leaves the loop time to yield")
        if period > longest:
            raise FieldError("driver.block_size", f"block_size {block} at {rate:g} Hz is a block every {period:.3g} s: "
                             f"at most {longest:.3g} s (supervision.no_data_s / {NO_DATA_BLOCKS}), or waiting for "
                             "a block is a no_data fault")
        seq = self.profile.sequence
        spans = [(f"profile.sequence.windows.{i}", w.end_s - w.start_s) for i, w in enumerate(seq.windows)]
        spans += [("profile.sequence.flow_window", seq.flow_window.end_s - seq.flow_window.start_s)] \
            if seq.flow_window is not None else []
        spans.append(("profile.sequence.offset_s", seq.offset_s))
        for field, span in spans:
            if span * rate < MIN_WINDOW_SAMPLES:
                raise FieldError(field, f"{span:g} s holds {span * rate:.3g} samples at {rate:g} Hz: a mean over "
                                 f"fewer than {MIN_WINDOW_SAMPLES} samples is mostly sensor noise")
        return self

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
def load_profile(path: str | Path) -> Profile:
    return load_model(Profile, path)


def _check_files(cfg: CellConfig, path: Path) -> None:
    """What must exist on disk when a cell config is loaded from a file (a recorded config
    is validated without these: its files belong to another machine and time)."""
    if cfg.driver.kind == "replay":  # relative to the working directory (docs/recording.md)
        referenced_file(cfg.driver.file, path, "driver.file")
    if not cfg.recording.enabled:
        return
    try:
        st = os.stat(cfg.recording.dir)
    except FileNotFoundError:
        return  # the recorder creates it
    except OSError as exc:  # a name too long, a path through a file
        raise ConfigError(f"{path}: recording.dir: {exc.strerror or exc}") from exc
    if not stat.S_ISDIR(st.st_mode):
        raise ConfigError(f"{path}: recording.dir: {one_line(cfg.recording.dir)} exists and is not a directory")


def load_cell_config(path: str | Path, overrides: dict[str, Any] | None = None) -> CellConfig:
    """Load a cell config. ``overrides`` replace top-level sections' keys, e.g.
    ``{"driver": {"clock": "virtual"}}`` (used by the demo and tests)."""
    path = Path(path)
    data = read_yaml(path)
    if not isinstance(data, dict):
        validate(CellConfig, data, path)  # says what the file holds instead of a mapping
    profile = data.get("profile")
    if isinstance(profile, str):
        data = {**data, "profile": load_profile(referenced_file(path.parent / profile, path, "profile").resolve())}
    elif isinstance(profile, dict):
        data = {**data, "profile": validate(Profile, profile, path, prefix="profile.")}
    for section, values in (overrides or {}).items():
        current = data.get(section, {})
        if isinstance(current, BaseModel):
            current = current.model_dump()
        if current is None or isinstance(current, dict):  # else the validation says what is wrong with it
            data = {**data, section: {**(current or {}), **values}}
    cfg = validate(CellConfig, data, path)
    _check_files(cfg, path)
    return cfg
