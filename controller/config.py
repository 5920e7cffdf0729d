"""Configuration: pydantic models loaded from YAML.

A bad file fails before anything starts, with one line per problem in the form
``FILE: field.path: reason``. Profiles may live in their own file (``profile: PATH``,
relative to the file that names it); their errors then name the profile file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal, TypeVar

import yaml
from pydantic import BaseModel, Field, ValidationError, model_validator

from drivers.config import DriverConfig
from drivers.errors import ConfigError
from drivers.hardware import Actuator, Circuit, GripperActuator, Hardware, Sensor
from drivers.models import StrictModel
from drivers.units import KPA

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


class SequenceConfig(StrictModel):
    """One actuation cycle (tank method, paper Methods "Size sensing with soft gripper"):
    charge the tank at P0, isolate it, open the actuation valve, hold while the windows are
    measured, vent."""

    method: Literal["tank"] = "tank"
    p0_kpa: float = Field(63.0, ge=-100, le=1000, description="tank charge pressure (gauge)")
    charge_s: float = Field(10.0, gt=0, le=600)
    isolate_s: float = Field(10.0, gt=0, le=600)
    actuate_s: float = Field(20.0, gt=0, le=3600)
    vent_s: float = Field(10.0, gt=0, le=600)
    offset_s: float = Field(1.0, gt=0, le=60, description="sensor offset: mean of this long before opening")
    windows: list[Window] = Field(default_factory=lambda: [Window(name="eq", start_s=4.0, end_s=5.0)],
                                  min_length=1, max_length=16)
    contact_threshold_kpa: float = Field(0.5, gt=0, le=100, description="dP level for t_c by threshold")
    smoothing_samples: int = Field(21, ge=3, le=1001, description="local quadratic regression span")

    @model_validator(mode="after")
    def _consistent(self) -> SequenceConfig:
        if self.offset_s > self.isolate_s:
            raise ValueError(f"offset_s ({self.offset_s}) must fit inside isolate_s ({self.isolate_s})")
        for w in self.windows:
            if w.end_s > self.actuate_s:
                raise ValueError(f"window {w.name!r} ends at {w.end_s} s, after the valve closes "
                                 f"(actuate_s = {self.actuate_s})")
        names = [w.name for w in self.windows]
        if len(set(names)) != len(names):
            raise ValueError(f"window names must be unique, got {names}")
        return self


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


class Profile(StrictModel):
    """One actuator or gripper: its hardware, its safe envelope and its cycle."""

    name: str = Field(min_length=1, max_length=80)
    description: str = ""
    circuit: Circuit = Circuit()
    actuator: Actuator = GripperActuator()
    sensor: Sensor = Sensor()
    tank_sensor: Sensor = Sensor(offset_kpa=0.0)
    limits: Limits = Limits(max_kpa=90.0, min_kpa=-5.0)
    sequence: SequenceConfig = SequenceConfig()

    @model_validator(mode="after")
    def _p0_inside_limits(self) -> Profile:
        p0 = self.sequence.p0_kpa
        if not self.limits.min_kpa <= p0 <= self.limits.max_kpa:
            raise ValueError(f"sequence.p0_kpa ({p0}) is outside limits "
                             f"[{self.limits.min_kpa}, {self.limits.max_kpa}] kPa")
        return self

    @property
    def hardware(self) -> Hardware:
        return Hardware(circuit=self.circuit, actuator=self.actuator, sensor=self.sensor,
                        tank_sensor=self.tank_sensor)


class PublisherConfig(StrictModel):
    """ZeroMQ endpoints. The command socket stays on loopback unless keys are configured
    (service hardening)."""

    pub: str = Field("tcp://127.0.0.1:5560", min_length=6)
    cmd: str = Field("tcp://127.0.0.1:5561", min_length=6)
    pressure_batch_s: float = Field(0.1, gt=0, le=10, description="pressure samples are sent in batches this long")
    heartbeat_s: float = Field(1.0, gt=0, le=60)


class CellConfig(StrictModel):
    """A whole cell: which driver, which actuator profile, where to publish."""

    driver: DriverConfig
    profile: Profile
    publisher: PublisherConfig = PublisherConfig()
    log_level: Literal["DEBUG", "INFO", "WARNING", "ERROR"] = "INFO"


# ---------------------------------------------------------------------- loading
def _format_errors(path: Path, exc: ValidationError, prefix: str = "") -> str:
    lines = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in err["loc"] if not str(p).startswith("function-after"))
        loc = f"{prefix}{loc}" if loc else (prefix.rstrip(".") or "(top level)")
        msg = err["msg"]
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
        raise ConfigError(_format_errors(Path(path), exc, prefix)) from exc


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
