"""Reaching the cell: the backend built as the config says (read-only unless the valves
are to move), connected within a timeout that names what did not answer and what to
check, and the robot's own account of itself from its dashboard server."""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from fluidsense.common.errors import DeviceTimeoutError, LinkLostError
from fluidsense.drivers.backend import Backend

log = logging.getLogger(__name__)

DASHBOARD_PORT = 29999  # UR's dashboard server (CB3 and e-Series)
#: read-only dashboard queries: key -> command
DASHBOARD_QUERIES = {"version": "PolyscopeVersion", "model": "get robot model", "robot_mode": "robotmode",
                     "safety_mode": "safetymode", "remote": "is in remote control"}
SAFETY_OK = ("NORMAL", "REDUCED")


def where(driver) -> str:
    """The device ports a driver talks to, for messages."""
    if driver.kind == "ur":
        return f"the robot at {driver.host} (RTDE port 30004)"
    if driver.kind == "modbus":
        arm = "" if driver.arm is None else f", the robot's RTDE port 30004 at {driver.arm.host or driver.host}"
        return f"the Modbus server at {driver.host}:{driver.port}{arm}"
    return f"the {driver.kind} cell"


def what_to_check(driver) -> str:
    if driver.kind == "ur":
        return (f"check that the robot is on and booted, that `ping {driver.host}` answers, that nothing else "
                "holds its RTDE inputs, and driver.host in the config")
    if driver.kind == "modbus":
        return (f"check that the box is on, that `ping {driver.host}` answers, that its Modbus server is enabled "
                f"(PolyScope: Installation > Fieldbus > Modbus) on port {driver.port}, and driver.host/port in the "
                "config")
    return "check the config"


async def connect(backend: Backend, driver, timeout_s: float) -> None:
    """Set the backend up within ``timeout_s``; a device that does not answer raises
    DeviceTimeoutError saying which and what to check."""
    try:
        async with asyncio.timeout(timeout_s):
            await backend.setup()
    except TimeoutError as exc:
        raise DeviceTimeoutError(f"no answer from {where(driver)} within {timeout_s:g} s: "
                                 f"{what_to_check(driver)}") from exc
    except LinkLostError as exc:
        raise DeviceTimeoutError(f"cannot reach {where(driver)} ({exc}): {what_to_check(driver)}") from exc


def robot_host(driver) -> str | None:
    """The UR robot behind a driver, whose dashboard tells its version and modes; None
    for a cell without one (a bare Modbus I/O module, the simulated cell)."""
    if driver.kind == "ur":
        return driver.arm.host or driver.host
    if driver.kind == "modbus" and driver.arm is not None:
        return driver.arm.host or driver.host
    return None


async def ask_dashboard(host: str, timeout_s: float, port: int = DASHBOARD_PORT) -> dict[str, str]:
    """The robot's answers to read-only dashboard queries. Raises OSError or TimeoutError."""
    async with asyncio.timeout(timeout_s):
        reader, writer = await asyncio.open_connection(host, port)
        try:
            await reader.readline()  # greeting
            answers: dict[str, Any] = {}
            for key, command in DASHBOARD_QUERIES.items():
                writer.write(f"{command}\n".encode())
                await writer.drain()
                answers[key] = (await reader.readline()).decode(errors="replace").strip()
        finally:
            writer.close()
    for key, prefix in (("robot_mode", "Robotmode:"), ("safety_mode", "Safetymode:")):
        answers[key] = answers[key].removeprefix(prefix).strip()
    return answers


def generation(version_text: str) -> str | None:
    """PolyScope's major version -> controller generation (3.x CB3, 5.x e-Series)."""
    for word in version_text.split():
        major = word.split(".", 1)[0]
        if major.isdigit() and "." in word:
            return {"3": "cb3", "5": "e-series"}.get(major)
    return None


def lost(driver, exc: Exception) -> DeviceTimeoutError:
    """The link went away during the check."""
    return DeviceTimeoutError(f"lost {where(driver)} during the check ({exc}): {what_to_check(driver)}")
