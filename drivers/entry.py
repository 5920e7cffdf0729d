"""What every driver is to the rest of the house: one registry entry.

A driver's config model (a subclass of ``DriverEntry`` with a ``kind``) names the module
that builds its backend, and answers what the commands outside drivers/ ask of a cell:
where it connects and what to check when it does not answer (``fluidsense check``), the
UR robot and control box behind it, files it reads, whether its samples come from a
seed. The defaults here describe a cell that has none of these; a driver overrides what
applies to it. Nothing outside drivers/ looks at ``kind`` to decide anything
(tests/unit/test_driver_registry.py checks it), so adding a driver touches its config, its
backend and the registry (drivers/registry.py) only: docs/architecture.md, "Adding a
driver".

Importing this imports pydantic only: the backend's module (and ur_rtde, pymodbus,
nidaqmx, the simulated plant) is imported when the backend is built.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar, Literal

from fluidsense.common.errors import DeviceTimeoutError
from fluidsense.common.hardware import Hardware
from fluidsense.common.models import StrictModel

if TYPE_CHECKING:
    from typing import Self

    from .backend import Backend
    from .ur.box import ControlBox
    from .ur.dashboard import Robot

BLOCK_SIZE = ("samples per delivered block. The block period block_size / rate_hz must be at least 5 ms (the sample "
              "loop yields to commands and signals only between blocks) and at most supervision.no_data_s / 5 "
              "(else waiting for a block is a no_data fault); the cell config checks both")


@dataclass(frozen=True)
class DeadLinkVent:
    """What puts the valves in their safe state when the link to the device dies, or the
    daemon with it (docs/safety.md, "Vent without the PC"): ``box_watchdog`` (a UR control
    box's own program or ur_rtde's RTDE watchdog), ``device_watchdog`` (the serial
    firmware's, a DAQ's timer), ``none`` (the outputs stay as last set until the daemon
    reconnects), ``no_link`` (the cell runs inside the daemon: nothing to lose)."""

    by: Literal["box_watchdog", "device_watchdog", "none", "no_link"]
    #: what vents and how it is set up, for an operator
    what: str
    #: the vent comes this long after the service's last heartbeat (None: none comes)
    timeout_s: float | None = None
    #: the reconnection back-off's longest wait (s): after the link returns, the daemon's
    #: next attempt (which writes the safe state first) may be this far away
    reconnect_max_s: float | None = None
    #: how to get a vent path where there is none, or None
    fix: str | None = None


class DriverEntry(StrictModel):
    """The base of every driver's config (``driver:`` in a cell config). Subclasses add
    ``kind: Literal[...]`` and their fields; methods only here, so a subclass's fields
    keep their order."""

    #: the module whose ``build(cfg, hardware, read_only=...)`` makes the Backend
    backend_module: ClassVar[str]
    #: a cell to connect to (False: a recording, which ``fluidsense check`` has nothing to look at)
    live: ClassVar[bool] = True

    def build(self, hardware: Hardware, read_only: bool = False) -> Backend:
        """Import the backend's module now and build it (drivers/registry.py's
        ``build_backend`` says what ``read_only`` means)."""
        return importlib.import_module(self.backend_module).build(self, hardware, read_only=read_only)

    def where(self) -> str:
        """The device ports the driver talks to, for messages."""
        return f"the {self.kind} cell"  # every entry has a kind (its subclass declares it)

    def what_to_check(self) -> str:
        """What an operator checks when the device does not answer."""
        return "check the config"

    def emulator_hint(self) -> str | None:
        """For a config of an emulated device (it names the emulator's control port): how
        to start the emulator, which is what is missing when nothing answers. None for a
        real device."""
        return None

    def unreachable(self, exc: BaseException, timeout_s: float | None = None) -> DeviceTimeoutError:
        """The device did not answer a first connection: what did not answer and what to
        do, the same words for ``fluidsense check`` and every job (exit 3, a timeout)."""
        why = f"no answer within {timeout_s:g} s" if timeout_s is not None else str(exc) or type(exc).__name__
        return DeviceTimeoutError(f"cannot reach {self.where()} ({why}): "
                                  f"{self.emulator_hint() or self.what_to_check()}")

    def robot(self) -> Robot | None:
        """The UR robot behind the driver, whose dashboard tells its version and modes;
        None for a cell without one."""
        return None

    def control_box(self) -> ControlBox | None:
        """The UR control box the driver reaches (its vent watchdog, its emulation by
        ``fluidsense simcell``); None for a cell without one."""
        return None

    def dead_link_vent(self) -> DeadLinkVent:
        """What vents the gripper when the link dies (docs/safety.md). A device without a
        watchdog of its own keeps its outputs: the default."""
        return DeadLinkVent("none", f"{self.where()} keeps its outputs as last set")

    def valves_on_sample_clock(self) -> bool:
        """The valves switch at the sample time a command names, on the samples' own clock
        (a simulated cell in virtual time): cycles and their references are then timed
        alike, and the profile's ``align_rise_kpa: auto`` leaves them so. False (the
        default): the command reaches the valve after the host got round to it, by as
        many ms as the PC was busy."""
        return False

    def needs_operator(self) -> bool:
        """Only an operator can place objects in front of the gripper (a real cell whose
        scene no software lays out): a calibration then asks for each target."""
        return False

    def files(self) -> dict[str, str]:
        """Fields that name a file which must exist when the config is loaded from a file
        (field -> path, relative to the working directory)."""
        return {}

    def samples_seed(self) -> int | None:
        """The seed that decides the cell's samples (same seed, same samples), or None for
        a device or a recording."""
        return None

    def for_job(self, seed: int) -> Self:
        """The driver as a CLI job runs it with ``--seed``: a simulated cell in virtual time
        with that seed; any other driver as it is."""
        return self
