"""The registry of drivers: a cell config's ``driver:`` section is one of the entries
below, chosen by its ``kind`` (a pydantic discriminated union). Each entry is a config
model (drivers/entry.py's ``DriverEntry``) that names its backend's module, imported only
when the backend is built, so a cell that does not ask for the simulated plant (or for
ur_rtde, pymodbus, nidaqmx) never imports it. Adding a driver adds one line to the union
(docs/architecture.md, "Adding a driver").

The simulated cell's entry is written here rather than in drivers/sim/: that package
loads the plant, and reading a config must not."""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal, get_args

from fluidsense.common.hardware import Hardware
from fluidsense.common.models import Integer, Real, StrictModel
from fluidsense.common.scenes import EmptyScene, Scene
from pydantic import Field

from .backend import Backend
from .daqmx.config import NiDaqDriverConfig
from .entry import BLOCK_SIZE, DeadLinkVent, DriverEntry
from .modbus.config import ModbusDriverConfig
from .recording.config import ReplayDriverConfig
from .serial.config import SerialDriverConfig
from .ur.config import UrDriverConfig


class Perturbations(StrictModel):
    """Deviations of the simulated cell from its calibrated state (stability studies)."""

    tank_warming_k: Real = Field(
        0.0, ge=-30, le=30, description="the isolated tank's gas warms by this much before the valve opens "
        "(supply air at another temperature than the room)")
    regulator_bias_kpa: Real = Field(0.0, ge=-50, le=50, description="the regulator lands this far off its setpoint")
    residual_kpa: Real = Field(0.0, ge=-50, le=50, description="the actuator starts holding this much gauge "
                               "pressure (a tube a previous run left not yet vented); it vents from there")


class SimDriverConfig(DriverEntry):
    """The simulated cell built from the paper's physics."""

    backend_module: ClassVar[str] = "fluidsense.drivers.sim.backend"

    kind: Literal["sim"] = "sim"
    clock: Literal["virtual", "realtime"] = Field(
        "realtime", description="virtual: samples as fast as the CPU allows; realtime: at the wall-clock pace")
    rate_hz: Real = Field(1000.0, ge=1, le=20_000)
    block_size: Integer = Field(10, ge=1, le=10_000, description=BLOCK_SIZE)
    seed: Integer = Field(0, ge=0, description="same seed, same samples")
    scene: Scene = EmptyScene()
    perturb: Perturbations = Perturbations()

    def samples_seed(self) -> int:
        return self.seed

    def dead_link_vent(self) -> DeadLinkVent:
        return DeadLinkVent("no_link", "the simulated cell runs inside the daemon: it has no link to lose, and it "
                            "stops with the daemon")

    def valves_on_sample_clock(self) -> bool:
        # virtual time: a command is an event at its sample time; in real time the cell may
        # already have produced samples past it, and the valve switches after those
        return self.clock == "virtual"

    def for_job(self, seed: int) -> SimDriverConfig:
        return self.model_copy(update={"clock": "virtual", "seed": seed})


# the registry: one entry per driver
AnyDriverConfig = (SimDriverConfig | UrDriverConfig | ModbusDriverConfig | SerialDriverConfig | NiDaqDriverConfig
                   | ReplayDriverConfig)
DriverConfig = Annotated[AnyDriverConfig, Field(discriminator="kind")]
ENTRIES: tuple[type[DriverEntry], ...] = get_args(AnyDriverConfig)


def kinds(overriding: object = None) -> list[str]:
    """The registered kinds; with ``overriding`` (a method of ``DriverEntry``), those whose
    entry overrides it: the drivers a command works with, for its messages."""
    return [entry.model_fields["kind"].default for entry in ENTRIES
            if overriding is None or getattr(entry, overriding.__name__) is not overriding]


def build_backend(cfg: AnyDriverConfig, hardware: Hardware, read_only: bool = False) -> Backend:
    """Import the selected backend lazily and build it. ``read_only``: a backend that
    connects and reads without writing anything to the device (no safe positions written
    at connection, no box watchdog installed, no arm control script uploaded; its valves
    and regulator refuse to move), for ``fluidsense check`` to look at a cell untouched.
    Its ``stop()`` must not be used (it vents): stop its devices one by one."""
    return cfg.build(hardware, read_only=read_only)
