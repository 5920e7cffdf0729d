"""Device interfaces: one async base class per device kind.

Every device has ``setup()`` / ``stop()`` and works as ``async with``. Public methods
check the request (names, limits) and then call a protected ``_method`` that touches
the hardware; backends only implement the protected methods.

Time: every command carries ``t``, the sample time (s) at which the controller took
the decision. Hardware acts at once and only logs it; the simulated cell schedules the
command at that sample time, which is what makes virtual time exact.
"""

from __future__ import annotations

import abc
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import CommandError, DriverError, NotSupportedError, SafetyError

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class SampleBlock:
    """A block of timestamped samples, all channels sampled at the same instants.

    ``values[i, j]`` is channel ``channels[j]`` at time ``t[i]``, in SI units (Pa gauge for
    pressure channels, standard m^3/s for flow channels). ``missed`` counts sample slots
    that the source could not fill before this block; they are reported, never
    interpolated. ``late`` counts samples in this block taken after their slot deadline
    (polled sources only).
    """

    seq: int
    t: np.ndarray
    values: np.ndarray
    channels: tuple[str, ...]
    missed: int = 0
    late: int = 0
    lateness_s: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.values.shape != (len(self.t), len(self.channels)):
            raise ValueError(
                f"block values shape {self.values.shape} does not match "
                f"{len(self.t)} samples x {len(self.channels)} channels"
            )

    def __len__(self) -> int:
        return len(self.t)

    def channel(self, name: str) -> np.ndarray:
        try:
            return self.values[:, self.channels.index(name)]
        except ValueError:
            raise KeyError(f"no channel {name!r} in block (have {self.channels})") from None

    @property
    def t_end(self) -> float:
        return float(self.t[-1])


class Device(abc.ABC):
    """Base of every device: lifecycle and context management."""

    def __init__(self, name: str) -> None:
        self.name = name
        self._connected = False

    @property
    def connected(self) -> bool:
        return self._connected

    async def setup(self) -> None:
        await self._setup()
        self._connected = True
        log.info("%s %s: set up", type(self).__name__, self.name)

    async def stop(self) -> None:
        if not self._connected:
            return
        try:
            await self._stop()
        finally:
            self._connected = False
            log.info("%s %s: stopped", type(self).__name__, self.name)

    async def _setup(self) -> None:  # pragma: no cover - default: nothing to open
        return None

    async def _stop(self) -> None:  # pragma: no cover - default: nothing to close
        return None

    def _require_connected(self) -> None:
        if not self._connected:
            raise DriverError(f"{type(self).__name__} {self.name} is not set up")

    async def __aenter__(self):
        await self.setup()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()


class SampleSource(Device):
    """Delivers timestamped sample blocks (pressure and, where fitted, flow channels)."""

    #: sample rate in Hz
    rate_hz: float
    #: channel names, e.g. ("p_act", "p_tank", "flow")
    channels: tuple[str, ...]
    #: True when samples are produced on demand (virtual time), False when they
    #: arrive at the device's pace
    virtual: bool = False

    async def read_block(self) -> SampleBlock:
        """The next block. Raises LinkLostError when the source is gone."""
        self._require_connected()
        return await self._read_block()

    @abc.abstractmethod
    async def _read_block(self) -> SampleBlock: ...


class ValveBank(Device):
    """Logical valves. ``open=True`` connects the valve's source side (regulator, tank)
    towards the actuator; ``open=False`` isolates it, and for the actuation valve vents
    the actuator. The safe state is therefore every valve closed."""

    names: tuple[str, ...]

    def __init__(self, name: str, names: Sequence[str]) -> None:
        super().__init__(name)
        self.names = tuple(names)
        self._state: dict[str, bool] = dict.fromkeys(self.names, False)

    def is_open(self, valve: str) -> bool:
        return self._state[self._check(valve)]

    @property
    def state(self) -> dict[str, bool]:
        return dict(self._state)

    def _check(self, valve: str) -> str:
        if valve not in self._state:
            raise CommandError(f"unknown valve {valve!r}; this cell has {list(self.names)}")
        return valve

    async def set(self, valve: str, open: bool, t: float) -> None:
        self._require_connected()
        self._check(valve)
        await self._set(valve, bool(open), t)
        if self._state[valve] != bool(open):
            log.debug("valve %s -> %s at t=%.3f", valve, "open" if open else "closed", t)
        self._state[valve] = bool(open)

    async def safe(self, t: float) -> None:
        """Close every valve: actuator vented, tank isolated. Tries every valve even if
        one fails, then raises the first failure."""
        first: Exception | None = None
        for valve in self.names:
            try:
                await self._set(valve, False, t)
                self._state[valve] = False
            except Exception as exc:  # noqa: BLE001 - keep venting the others
                log.error("could not close valve %s: %s", valve, exc)
                first = first or exc
        if first is not None:
            raise DriverError("safe state incomplete: a valve did not close") from first

    @abc.abstractmethod
    async def _set(self, valve: str, open: bool, t: float) -> None: ...


class Regulator(Device):
    """Proportional pressure regulator (setpoint in Pa gauge). The controller installs
    the profile's limits; a setpoint outside them is refused before it reaches the
    device."""

    def __init__(self, name: str, min_pa: float = -float("inf"), max_pa: float = float("inf")) -> None:
        super().__init__(name)
        self.min_pa = min_pa
        self.max_pa = max_pa
        self.setpoint_pa: float = 0.0

    def set_limits(self, min_pa: float, max_pa: float) -> None:
        if not min_pa <= max_pa:
            raise SafetyError(f"regulator limits min {min_pa} Pa > max {max_pa} Pa")
        self.min_pa, self.max_pa = min_pa, max_pa

    async def set_setpoint(self, pressure_pa: float, t: float) -> None:
        self._require_connected()
        if not np.isfinite(pressure_pa) or not self.min_pa <= pressure_pa <= self.max_pa:
            raise SafetyError(
                f"regulator setpoint {pressure_pa / 1e3:.2f} kPa outside the profile's "
                f"limits [{self.min_pa / 1e3:.2f}, {self.max_pa / 1e3:.2f}] kPa"
            )
        await self._set_setpoint(float(pressure_pa), t)
        self.setpoint_pa = float(pressure_pa)

    @abc.abstractmethod
    async def _set_setpoint(self, pressure_pa: float, t: float) -> None: ...


class FlowController(Device):
    """Mass flow controller: standard volumetric flow setpoint in standard m^3/s."""

    def __init__(self, name: str, max_flow: float) -> None:
        super().__init__(name)
        self.max_flow = max_flow
        self.flow: float = 0.0

    async def set_flow(self, flow: float, t: float) -> None:
        self._require_connected()
        if not np.isfinite(flow) or not 0.0 <= flow <= self.max_flow:
            raise SafetyError(f"flow setpoint {flow:.3g} m^3/s outside [0, {self.max_flow:.3g}]")
        await self._set_flow(float(flow), t)
        self.flow = float(flow)

    @abc.abstractmethod
    async def _set_flow(self, flow: float, t: float) -> None: ...


class SceneControl(Device):
    """Places objects in front of the actuator. Only the simulated cell has one; on a
    real cell the operator or the arm does this."""

    @abc.abstractmethod
    async def set_scene(self, scene: Any, t: float) -> None: ...

    def truth(self) -> dict[str, Any]:
        """Ground truth of the current scene (simulated cells only)."""
        raise NotSupportedError("this backend has no ground truth")


@dataclass
class Backend:
    """One cell: the devices a driver provides. Optional devices are None when absent."""

    name: str
    source: SampleSource
    valves: ValveBank
    regulator: Regulator | None = None
    flow: FlowController | None = None
    scene: SceneControl | None = None
    arm: Any = None
    extras: dict[str, Any] = field(default_factory=dict)

    def devices(self) -> list[Device]:
        found = [self.source, self.valves, self.regulator, self.flow, self.scene, self.arm]
        return [d for d in found if d is not None]

    async def setup(self) -> None:
        done: list[Device] = []
        try:
            for dev in self.devices():
                await dev.setup()
                done.append(dev)
        except BaseException:
            for dev in reversed(done):
                await dev.stop()
            raise

    async def stop(self, t: float | None = None) -> None:
        """Vent first, then close every device."""
        if self.valves.connected:
            try:
                await self.valves.safe(t if t is not None else float("nan"))
            except Exception as exc:  # noqa: BLE001 - closing must go on
                log.error("venting at stop failed: %s", exc)
        for dev in reversed(self.devices()):
            await dev.stop()

    async def __aenter__(self) -> Backend:
        await self.setup()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()
