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
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from fluidsense.common.errors import (
    CommandError,
    DeviceTimeoutError,
    DriverError,
    LinkLostError,
    NotSupportedError,
    SafetyError,
)
from fluidsense.common.samples import SampleBlock, SampleClock

log = logging.getLogger(__name__)


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

    @property
    def clock_origin_s(self) -> float | None:
        """``time.monotonic()`` of sample time 0, when samples are taken in real time (the
        monotonic clock is shared by every process of the machine: other processes can
        turn sample times into their own clock). None in virtual time."""
        return None

    async def read_block(self) -> SampleBlock:
        """The next block. Raises LinkLostError when the source is gone."""
        self._require_connected()
        return await self._read_block()

    @abc.abstractmethod
    async def _read_block(self) -> SampleBlock: ...


class ValveBank(Device):
    """Logical valves. ``open=True`` connects the valve's source side (regulator, tank,
    flow controller) towards the actuator; for a separate vent valve, open vents the
    actuator. Each valve has a safe position (``safe``: name -> open): together they
    leave the actuator vented and the tank isolated."""

    #: the device can report its outputs (``_read_positions``)
    reports_outputs = False

    def __init__(self, name: str, safe: dict[str, bool]) -> None:
        super().__init__(name)
        self.names = tuple(safe)
        self.safe_positions = dict(safe)
        self._state: dict[str, bool] = dict(safe)
        #: positions as the device last reported them, and when (time.monotonic()); None
        #: until read, and for a device that cannot report its outputs
        self.reported: dict[str, bool] | None = None
        self.reported_at: float | None = None
        #: why the outputs cannot be known now (the last read or write failed), else None
        self.report_error: str | None = None
        #: writes so far: a read-back that saw no write during it can be held against
        #: what was commanded
        self.writes = 0

    def is_open(self, valve: str) -> bool:
        return self._state[self._check(valve)]

    @property
    def state(self) -> dict[str, bool]:
        return dict(self._state)

    @property
    def in_safe_state(self) -> bool:
        return self._state == self.safe_positions

    def _check(self, valve: str) -> str:
        if valve not in self._state:
            raise CommandError(f"unknown valve {valve!r}; this cell has {list(self.names)}")
        return valve

    async def set(self, valve: str, open: bool, t: float) -> None:
        self._require_connected()
        self._check(valve)
        await self._write(valve, bool(open), t)
        if self._state[valve] != bool(open):
            log.debug("valve %s -> %s at t=%.3f", valve, "open" if open else "closed", t)
        self._state[valve] = bool(open)

    async def safe(self, t: float) -> None:
        """Every valve to its safe position: actuator vented, tank isolated. Tries every
        valve even if one fails, then raises the first failure."""
        first: tuple[str, Exception] | None = None
        for valve, position in self.safe_positions.items():
            try:
                await self._write(valve, position, t)
                self._state[valve] = position
            except Exception as exc:  # noqa: BLE001 - keep venting the others
                log.error("could not put valve %s in its safe position: %s", valve, exc)
                first = first or (valve, exc)
        if first is not None:
            valve, exc = first
            raise same_family(exc, f"safe state incomplete: valve {valve} did not move: {exc}") from exc

    async def read_back(self) -> dict[str, bool] | None:
        """The valve positions the device reports now (its output register, not what was
        last commanded); None when this device cannot report them. A failed read raises."""
        self._require_connected()
        try:
            positions = await self._read_positions()
        except Exception as exc:
            self.report_error = f"read failed: {exc}"
            raise
        if positions is not None:
            self.reported, self.reported_at, self.report_error = dict(positions), time.monotonic(), None
        return positions

    async def _write(self, valve: str, open: bool, t: float) -> None:
        self.writes += 1
        try:
            await self._set(valve, open, t)
        except Exception as exc:
            self.report_error = f"write failed: {exc}"
            raise

    async def disagreement(self) -> dict[str, bool] | None:
        """Read back; the valves the device reports otherwise than commanded (a device
        that does not do what it was told: an output held by the box, a stuck driver),
        or None when they agree, cannot be read, or a write came during the read."""
        before, commanded = self.writes, self.state
        positions = await self.read_back()
        if positions is None or self.writes != before:
            return None
        wrong = {v: p for v, p in positions.items() if commanded.get(v) != p}
        return wrong or None

    async def confirm_safe(self, t: float) -> bool | None:
        """Every valve to its safe position, then read back: True when the device reports
        the safe positions, False when it reports anything else, None when it cannot
        report. Raises when a write or the read fails (the link is down)."""
        await self.safe(t)
        confirmed = self.reports_safe(await self.read_back())
        if confirmed is False:
            log.error("%s: the safe state was written but the device reports %s", self.name, self.reported)
        return confirmed

    def reports_safe(self, positions: dict[str, bool] | None) -> bool | None:
        """Whether read-back ``positions`` are the safe ones (None: nothing was read)."""
        if positions is None:
            return None
        return all(p == self.safe_positions.get(v) for v, p in positions.items())

    def age_s(self) -> float | None:
        """Seconds since the device last reported its outputs (None: never)."""
        return None if self.reported_at is None else time.monotonic() - self.reported_at

    async def _read_positions(self) -> dict[str, bool] | None:
        """Backends that can read their outputs back override this."""
        return None

    @abc.abstractmethod
    async def _set(self, valve: str, open: bool, t: float) -> None: ...


def same_family(cause: Exception, message: str) -> DriverError:
    """A DriverError saying ``message`` of ``cause``'s family: a lost link or a device that
    did not answer stays one (a connection retries those; a hiccup at start-up is not a bad
    device), anything else (a device that refused) is a plain DriverError."""
    for family in (LinkLostError, DeviceTimeoutError):
        if isinstance(cause, family):
            return family(message)
    return DriverError(message)


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
    """Mass flow controller. A setpoint profile is a piecewise-linear flow (standard
    m^3/s) against sample time, zero outside it; the device follows it by itself."""

    def __init__(self, name: str, max_flow: float) -> None:
        super().__init__(name)
        self.max_flow = max_flow

    async def set_profile(self, times: Sequence[float], flows: Sequence[float], t: float) -> None:
        self._require_connected()
        tt, qq = np.asarray(times, dtype=float), np.asarray(flows, dtype=float)
        if tt.shape != qq.shape or tt.ndim != 1 or np.any(np.diff(tt) < 0):
            raise CommandError("flow profile needs matching, time-ordered points")
        if not np.all(np.isfinite(qq)) or np.any(qq < 0) or np.any(qq > self.max_flow):
            raise SafetyError(f"flow profile outside [0, {self.max_flow:.3g}] m^3/s")
        await self._set_profile(tt, qq, t)

    async def stop_flow(self, t: float) -> None:
        await self.set_profile([t], [0.0], t)

    @abc.abstractmethod
    async def _set_profile(self, times: np.ndarray, flows: np.ndarray, t: float) -> None: ...


Pose = tuple[float, float, float, float, float, float]


class Arm(Device):
    """A robot arm: linear moves of the tool centre point, its pose, protective stop.

    Poses are UR's [x, y, z, rx, ry, rz] (m, rad) in the base frame. ``move_l`` returns
    when the tool has arrived. The public method refuses what the arm must not do
    (non-finite poses, speeds beyond the configured limits, moving while protective-
    stopped); the protected one drives the hardware.
    """

    def __init__(self, name: str, max_speed: float = 1.0, max_acc: float = 3.0) -> None:
        super().__init__(name)
        self.max_speed = max_speed
        self.max_acc = max_acc
        self.clock: SampleClock | None = None

    def use_clock(self, clock: SampleClock) -> None:
        """The controller's sample clock (``now``, ``wait_until(t)``), for arms that move
        in sample time."""
        self.clock = clock

    async def move_l(self, pose: Sequence[float], speed: float, acc: float, t: float) -> None:
        self._require_connected()
        target = tuple(float(v) for v in pose)
        if len(target) != 6 or not all(np.isfinite(target)):
            raise CommandError(f"a pose is 6 finite numbers [x, y, z, rx, ry, rz], got {list(pose)!r}")
        if not 0 < speed <= self.max_speed or not 0 < acc <= self.max_acc:
            raise SafetyError(f"move at {speed} m/s, {acc} m/s^2 outside (0, {self.max_speed}] m/s, "
                              f"(0, {self.max_acc}] m/s^2")
        if self.protective_stopped:
            raise SafetyError("the arm is protective-stopped")
        await self._move_l(target, float(speed), float(acc), t)

    async def stop_motion(self, t: float) -> None:
        if self.connected:
            await self._stop_motion(t)

    @property
    @abc.abstractmethod
    def tcp_pose(self) -> Pose: ...

    @property
    @abc.abstractmethod
    def protective_stopped(self) -> bool: ...

    @abc.abstractmethod
    async def _move_l(self, pose: Pose, speed: float, acc: float, t: float) -> None: ...

    @abc.abstractmethod
    async def _stop_motion(self, t: float) -> None: ...


class SceneControl(Device):
    """Places objects in front of the actuator. Only the simulated cell has one; on a
    real cell the operator or the arm does this."""

    @abc.abstractmethod
    async def set_scene(self, scene: Any, t: float) -> None: ...

    async def set_world(self, world: Any, t: float) -> None:
        """Lay out a work cell (slots and objects) for an arm to work in."""
        raise NotSupportedError("this backend cannot lay out a work cell")

    def truth(self) -> dict[str, Any]:
        """Ground truth of the current scene (simulated cells only)."""
        raise NotSupportedError("this backend has no ground truth")

    async def read_truth(self) -> dict[str, Any]:
        """``truth()``, also where the simulated cell runs in another process."""
        return self.truth()


class BoxWatchdog(Device):
    """The far side's watchdog: equipment that puts the valves in their safe state by
    itself when the service's heartbeat stops for ``timeout_s`` (the PC, the daemon or
    the link died). The controller's sample loop calls ``kick`` while it makes progress,
    so a stalled loop stops the heartbeat too."""

    def __init__(self, name: str, timeout_s: float) -> None:
        super().__init__(name)
        self.timeout_s = timeout_s

    async def kick(self) -> None:
        self._require_connected()
        await self._kick()

    async def ensure_running(self) -> None:
        """Before a cycle: what the watchdog guards runs (after the watchdog fired, the box
        holds its outputs safe until it does)."""
        self._require_connected()
        await self._ensure_running()

    @abc.abstractmethod
    async def _kick(self) -> None: ...

    async def _ensure_running(self) -> None:
        return None
