"""A UR robot's dashboard server (port 29999, CB3 and e-Series): read-only queries of its
version and modes, which ``fluidsense check`` reports before it connects the driver."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass
from typing import Any

DASHBOARD_PORT = 29999
#: read-only dashboard queries: key -> command
DASHBOARD_QUERIES = {"version": "PolyscopeVersion", "model": "get robot model", "robot_mode": "robotmode",
                     "safety_mode": "safetymode", "remote": "is in remote control"}
#: safety modes in which the robot runs programs
SAFETY_OK = ("NORMAL", "REDUCED")


@dataclass(frozen=True)
class Robot:
    """The UR robot behind a cell's driver."""

    host: str
    #: the controller generation the config says the robot is (``driver.controller``);
    #: None when the config does not say it of the robot
    generation: str | None = None
    port: int = DASHBOARD_PORT

    async def ask(self, timeout_s: float) -> dict[str, str]:
        return await ask_dashboard(self.host, timeout_s, self.port)


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
