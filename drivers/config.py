"""Driver selection: a pydantic discriminated union on ``kind`` (``sim``, ``ur``,
``modbus``, ``serial``, ``nidaqmx``, ``replay``); the chosen backend's module is imported only when it is
built, so a cell that does not ask for the simulated plant (or for ur_rtde, pymodbus, nidaqmx) never imports it."""

from __future__ import annotations

import importlib
from typing import Annotated, Literal

from fluidsense.common.hardware import Hardware
from fluidsense.common.models import Integer, Real, StrictModel
from fluidsense.common.scenes import EmptyScene, Scene
from pydantic import Field

from .backend import Backend
from .daqmx.config import NiDaqDriverConfig
from .io import BLOCK_SIZE
from .modbus.config import ModbusDriverConfig
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


class SimDriverConfig(StrictModel):
    """The simulated cell built from the paper's physics."""

    kind: Literal["sim"] = "sim"
    clock: Literal["virtual", "realtime"] = Field(
        "realtime", description="virtual: samples as fast as the CPU allows; realtime: at the wall-clock pace")
    rate_hz: Real = Field(1000.0, ge=1, le=20_000)
    block_size: Integer = Field(10, ge=1, le=10_000, description=BLOCK_SIZE)
    seed: Integer = Field(0, ge=0, description="same seed, same samples")
    scene: Scene = EmptyScene()
    perturb: Perturbations = Perturbations()


class ReplayDriverConfig(StrictModel):
    """A recording (``fluidsense run`` writes them) played back in virtual time: its
    samples as they were delivered; valves cannot be commanded (docs/recording.md)."""

    kind: Literal["replay"] = "replay"
    file: str = Field(min_length=1, description="the recording (.mcap)")


AnyDriverConfig = (SimDriverConfig | UrDriverConfig | ModbusDriverConfig | SerialDriverConfig | NiDaqDriverConfig
                   | ReplayDriverConfig)
DriverConfig = Annotated[AnyDriverConfig, Field(discriminator="kind")]

_BACKEND_MODULES = {
    "sim": "fluidsense.drivers.sim",
    "ur": "fluidsense.drivers.ur.backend",
    "modbus": "fluidsense.drivers.modbus.backend",
    "serial": "fluidsense.drivers.serial.backend",
    "nidaqmx": "fluidsense.drivers.daqmx.backend",
    "replay": "fluidsense.drivers.replay",
}


def build_backend(cfg: AnyDriverConfig, hardware: Hardware, read_only: bool = False) -> Backend:
    """Import the selected backend lazily and build it. ``read_only``: a backend that
    connects and reads without writing anything to the device (no safe positions written
    at connection, no box watchdog installed, no arm control script uploaded; its valves
    and regulator refuse to move), for ``fluidsense check`` to look at a cell untouched.
    Its ``stop()`` must not be used (it vents): stop its devices one by one."""
    module = importlib.import_module(_BACKEND_MODULES[cfg.kind])
    return module.build(cfg, hardware, read_only=read_only)
