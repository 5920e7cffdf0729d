"""``fluidsense check``: bring-up of a real cell. Connects through the configured driver
and reports what it finds against the config and the profile: the robot's version and
modes, the rate the device really delivers, each sensor's level and noise, the valve
outputs as read back. Read-only unless ``actuate``: then it vents, pulses each valve in
turn and checks that the pressures answer as the wiring says, and always ends in the
safe state (regulator at 0, valves safe, read back), also when interrupted or failing.

The modules: ``connect`` (reaching the cell), ``readings`` (looking), ``actuate``
(pulsing), ``findings`` (what is reported)."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from fluidsense.common.errors import ConfigError, LinkLostError
from fluidsense.controller.safety.ventpath import vent_path, vent_path_line
from fluidsense.drivers.registry import build_backend
from fluidsense.drivers.ur.dashboard import SAFETY_OK, generation

from . import actuate, connect, readings
from .findings import Findings, Problem

log = logging.getLogger(__name__)

__all__ = ["CheckOptions", "Problem", "run_check"]


@dataclass(frozen=True)
class CheckOptions:
    seconds: float = 3.0  # sampling time of the read-only look
    timeout_s: float = 10.0  # each device's answer
    actuate: bool = False
    test_kpa: float | None = None  # the regulator during the pulses (None: from the profile)
    pulse_s: float = 0.6  # each step's duration
    zero_kpa: float = 2.0  # the vented actuator's sensor within this of 0 kPa gauge


def describe_plan(cfg, opts: CheckOptions) -> str:
    """What --actuate will do, for the confirmation question."""
    p = actuate.test_pressure_pa(cfg.profile, opts.test_kpa) / 1e3
    valves = ", ".join(cfg.profile.hardware.circuit.safe_valves)
    return (f"This vents the cell, sets the regulator to {p:+.1f} kPa and opens each valve in turn ({valves}) for "
            f"{opts.pulse_s:g} s, then vents it again. The gripper must be free and empty, and hands out of it.")


async def run_check(cfg, path: str, opts: CheckOptions, say: Callable[[str], None],
                    on_backend: Callable[[Any], None] | None = None) -> list[Problem]:
    """The problems found (none: the cell matches its config). Raises DeviceTimeoutError
    when a device does not answer. ``on_backend`` is given the backend before it connects
    (the caller tells where a stop left its valves)."""
    driver = cfg.driver
    if not driver.live:
        raise ConfigError(f"{path}: driver.kind: check looks at a live cell; a recording has nothing to connect to")
    out = Findings(say)
    _vent_path(cfg, out)
    await _look_at_robot(driver, opts, out)
    backend = build_backend(driver, cfg.profile.hardware, read_only=not opts.actuate)
    if on_backend is not None:
        on_backend(backend)
    out.section(f"connecting to {driver.where()}" + ("" if opts.actuate else " (read-only)"))
    await connect.connect(backend, driver, opts.timeout_s)
    if opts.actuate:
        out.info("connected; every valve written to its safe position and read back")
    try:
        rig = readings.Rig(backend, kick=opts.actuate)
        await _look(cfg, backend, rig, opts, out)
        if opts.actuate:
            await _pulse(cfg, backend, rig, opts, out)
    except LinkLostError as exc:
        raise connect.lost(driver, exc) from exc
    finally:
        await _close(backend, opts.actuate)
    out.section("result")
    if out.ok:
        out.info("everything matches the config")
    for p in out.problems:
        out.info(p.line())
    for w in out.warnings:
        out.info(f"WARNING {w}")
    return out.problems


def _vent_path(cfg, out: Findings) -> None:
    """From the config alone: said before anything connects, so a cell that cannot be
    reached hears it too."""
    path = vent_path(cfg)
    out.section("vent path on a dead link (the link or the daemon dies)")
    if path["by"] == "none":
        out.warning(vent_path_line(path))
    else:
        out.info(vent_path_line(path))


async def _look_at_robot(driver, opts: CheckOptions, out: Findings) -> None:
    robot = driver.robot()
    if robot is None:
        return
    out.section(f"robot at {robot.host} (dashboard port {robot.port})")
    try:
        answers = await robot.ask(opts.timeout_s)
    except (OSError, TimeoutError) as exc:
        out.info(f"the dashboard server did not answer ({exc or 'timeout'}): version and modes unknown")
        return
    out.info(f"{answers['model']}, {answers['version']}; robot mode {answers['robot_mode']}, safety mode "
             f"{answers['safety_mode']}; remote control: {answers['remote']}")
    gen = generation(answers["version"])
    if robot.generation is not None and gen is not None and gen != robot.generation:
        out.problem("driver.controller", f"the config says {robot.generation}, the robot runs {answers['version']} "
                    f"({gen})", f"set driver.controller: {gen} (RTDE rate: e-Series 500 Hz, CB3 125 Hz)")
    if answers["safety_mode"] not in SAFETY_OK:
        out.problem("robot", f"safety mode {answers['safety_mode']}",
                    "clear it on the teach pendant before running the daemon (a stopped robot is a fault)")


async def _look(cfg, backend, rig, opts: CheckOptions, out: Findings) -> None:
    out.section("valve outputs as the device reports them")
    vented = await readings.judge_valves(backend, cfg.profile.hardware.circuit.venting_valves, out)
    out.section(f"sampling for {opts.seconds:g} s")
    sampling = await readings.sample(rig, opts.seconds)
    readings.judge_rate(sampling, backend.source.rate_hz, backend.source.virtual, out, readings.load_per_cpu())
    readings.judge_channels(sampling, cfg, vented is not False, opts.zero_kpa, out)


async def _pulse(cfg, backend, rig, opts: CheckOptions, out: Findings) -> None:
    hw = cfg.profile.hardware
    steps = actuate.plan(hw.circuit, backend.source.channels)
    p_test = actuate.test_pressure_pa(cfg.profile, opts.test_kpa)
    out.section(f"pulsing the valves, regulator at {p_test / 1e3:+.1f} kPa")
    if not steps:
        out.info(f"a {hw.circuit.kind} circuit has no valve pulse plan: only tank and regulated circuits are checked")
        return
    if backend.regulator is not None:
        backend.regulator.set_limits(cfg.profile.limits.min_pa, cfg.profile.limits.max_pa)
    if backend.watchdog is not None:
        await backend.watchdog.ensure_running()  # a box whose watchdog fired holds its outputs safe until then
    pulser = actuate.Pulser(backend, rig, cfg.profile, out, p_test, opts.pulse_s)
    try:
        await pulser.run(steps)
    except actuate.Unsafe as exc:
        out.problem("limits", f"stopped pulsing: {exc}", "vented; check the regulator's range and the wiring")
    finally:
        out.section("back to the safe state")
        await _uninterrupted(actuate.finish(backend, rig, out))


async def _uninterrupted(coro) -> None:
    """Run ``coro`` to its end even when the caller is cancelled meanwhile (a Ctrl-C while
    venting must not cut the venting short); the cancellation is passed on afterwards."""
    task = asyncio.ensure_future(coro)
    cancelled = False
    while not task.done():
        try:
            await asyncio.shield(task)
        except asyncio.CancelledError:
            cancelled = cancelled or not task.done()
    if cancelled:
        raise asyncio.CancelledError
    task.result()


async def _close(backend, actuated: bool) -> None:
    """A read-only backend is closed device by device (its stop() would vent: a write);
    one that moved the valves vents once more on the way out."""
    if actuated:
        await backend.stop(None)
        return
    for dev in reversed(backend.devices()):
        try:
            await dev.stop()
        except Exception as exc:  # noqa: BLE001 - close the others
            log.error("closing %s: %s", dev.name, exc)
