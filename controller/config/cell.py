"""A cell config: which driver, which profile, where to publish, how to supervise and
record. A bad file fails before anything starts, with one line per problem in the form
``FILE: field.path: reason``. Profiles may live in their own file (``profile: PATH``,
relative to the file that names it); their errors then name the profile file.
"""

from __future__ import annotations

import math
import os
import stat
from pathlib import Path
from typing import Annotated, Any, Literal

from fluidsense.common.errors import ConfigError
from fluidsense.common.files import one_line
from fluidsense.common.models import FieldError, Integer, Real, StrictModel
from fluidsense.drivers.registry import DriverConfig
from fluidsense.drivers.recording.config import RecordingConfig
from pydantic import BaseModel, Field, ValidationInfo, field_validator, model_validator

from .curve import ALLOW_ANY, count_public_keys, read_secret_key
from .gripper import GripperConfig, check_calibrations, resolve_calibrations
from .loading import load_model, named_file, read_yaml, referenced_file, validate
from .profile import Profile


#: cycle events and logs per second the publisher's queue is sized for (PublisherConfig.hwm_messages)
EVENT_RATE_HZ = 2.0


class Supervision(StrictModel):
    """Thresholds of the safety supervisor (controller/safety/supervisor.py)."""

    stuck_s: Real = Field(0.25, gt=0, le=60, description="a pressure reading that does not change for this long is stuck")
    freeze_s: Real = Field(
        0.05, gt=0, le=60, description="p_act unchanged this long (but under stuck_s) inside a cycle's measured span "
        "marks its reading unreliable (a box or sensor that froze); a live one repeats a reading for a few ms "
        "(docs/safety.md)")
    leak_kpa_per_s: Real = Field(0.1, gt=0, le=100, description="decay towards atmosphere while held that is a leak")
    no_data_s: Real = Field(0.5, gt=0, le=60, description="real time: no block for this long is a fault")
    overrun_s: Real = Field(0.25, gt=0, le=60, description="real time: the loop this far behind the samples is a fault")

    @model_validator(mode="after")
    def _freeze_under_stuck(self) -> Supervision:
        if self.freeze_s >= self.stuck_s:
            raise ValueError(f"freeze_s ({self.freeze_s:g}) must be below stuck_s ({self.stuck_s:g}): a longer "
                             "freeze is a sensor_stuck fault")
        return self


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
    queue_s: Real = Field(30.0, gt=0, le=600, description=(
        "seconds of messages the publisher keeps for a subscriber that falls behind; beyond that it drops "
        "(the high-water mark, in messages: queue_s x the message rate, see hwm_messages)"))

    @property
    def hwm_messages(self) -> int:
        """The publisher's per-subscriber high-water mark: ``queue_s`` of the message rate,
        which is one pressure batch per ``pressure_batch_s``, one status heartbeat per
        ``heartbeat_s`` and at most EVENT_RATE_HZ of cycle events and logs (a grip cycle
        sends about ten events in a second or more). At the defaults: 30 s x 13/s = 390
        messages, about 1 MB per slow subscriber at 2.5 kB a message; the 10,000 it was
        grew the daemon by 12.6 MB over 8 hours with one such subscriber (docs/soak.md)."""
        rate = 1.0 / self.pressure_batch_s + 1.0 / self.heartbeat_s + EVENT_RATE_HZ
        return max(10, math.ceil(self.queue_s * rate))

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


class ReferenceKeeping(StrictModel):
    """The daemon keeps its free-air references on disk and takes them back at start when
    they still belong to the cell (controller/cycles/kept.py, docs/recording.md)."""

    keep: bool = Field(True, description="keep them (false: a restarted daemon starts without any)")
    file: str | None = Field(None, min_length=1, max_length=4096, description="the file, relative to the daemon's "
                             "working directory; default: references.json in recording.dir")


class LiveConfig(StrictModel):
    """The live view (docs/recording.md, "Live view"): the Foxglove WebSocket protocol served by a
    process of its own, with the recording's channels, schemas and timestamps. Loopback by
    default: a viewer sees every sample and event."""

    enabled: bool = Field(False, description="serve the live view (fluidsense run --live [HOST:]PORT turns it on)")
    host: str = Field("127.0.0.1", min_length=1, max_length=253, pattern=r"^[A-Za-z0-9.:_-]+$",
                      description="address to listen on; 0.0.0.0 opens it to the network")
    port: Integer = Field(8765, ge=1, le=65535)
    queue: Integer = Field(10_000, ge=10, le=1_000_000, description="messages the daemon queues for the "
                           "live process; past it they are dropped and counted, never waited for")
    backlog: Integer = Field(1024, ge=16, le=100_000, description="messages queued per viewer; a slow "
                             "viewer loses the oldest")


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
    references: ReferenceKeeping = ReferenceKeeping()
    live: LiveConfig = LiveConfig()
    loop: LoopConfig = LoopConfig()
    gripper: GripperConfig = GripperConfig()
    log_level: Literal["DEBUG", "INFO", "WARNING", "ERROR"] = "INFO"

    @field_validator("profile")
    @classmethod
    def _timed_like_the_driver(cls, profile: Profile, info: ValidationInfo) -> Profile:
        """``align_rise_kpa: auto`` on a driver whose valves switch on the samples' clock:
        cycles and references are timed alike there, and aligning would only hide contacts
        on the first rise (the stiffness scene's soft plate, met during it, read 4.69 mm of
        indentation instead of 0.93). The cell's profile keeps the commanded timing."""
        driver = info.data.get("driver")
        seq = profile.sequence
        if seq.align_rise_kpa == "auto" and driver is not None and driver.valves_on_sample_clock():
            return profile.model_copy(update={"sequence": seq.model_copy(update={"align_rise_kpa": None})})
        return profile

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
            raise FieldError("driver.wiring", "; ".join(problems))
        return self


# ---------------------------------------------------------------------- loading
def load_profile(path: str | Path) -> Profile:
    return load_model(Profile, path)


def _check_files(cfg: CellConfig, path: Path) -> None:
    """What must exist on disk when a cell config is loaded from a file (a recorded config
    is validated without these: its files belong to another machine and time)."""
    for field, name in cfg.driver.files().items():  # relative to the working directory (docs/recording.md)
        referenced_file(name, path, f"driver.{field}")
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
        data = {**data, "profile": load_profile(named_file(profile, path, "profile", "profiles", ".yaml").resolve())}
    elif isinstance(profile, dict):
        data = {**data, "profile": validate(Profile, profile, path, prefix="profile.")}
    for section, values in (overrides or {}).items():
        current = data.get(section, {})
        if isinstance(current, BaseModel):
            current = current.model_dump()
        if current is None or isinstance(current, dict):  # else the validation says what is wrong with it
            data = {**data, section: {**(current or {}), **values}}
    cfg = validate(CellConfig, resolve_calibrations(data, path), path)
    _check_files(cfg, path)
    check_calibrations(cfg.gripper, cfg.profile.name, path)
    return cfg
