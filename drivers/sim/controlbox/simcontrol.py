"""The emulator's own control channel: what a person does at a real cell (press the
e-stop, wire a signal to an input, read what the arm did), as JSON lines.

The process entry reads one JSON object per line on stdin and answers one JSON object
per line on stdout: ``{"cmd": "state"}`` returns a snapshot of the model;
``{"cmd": "set", ...}`` changes what is given, e.g.
``{"cmd": "set", "protective_stop": true}`` or
``{"cmd": "set", "analog_input": {"channel": 0, "value": 4.5, "domain": "VOLTAGE"}}``.
Replies are ``{"ok": true, ...}`` or ``{"ok": false, "error": "..."}``, with the
request's ``id`` echoed when it has one. This is not part of the UR control box.
"""

from __future__ import annotations

import json
import logging
from typing import Annotated, Any, Literal

from pydantic import Field, TypeAdapter, ValidationError

from ...errors import FluidsenseError, NotSupportedError
from ...models import StrictModel
from .box import ControlBox
from .model import DIGITAL_MASK, AnalogDomain, RobotMode

log = logging.getLogger(__name__)

Pose6 = tuple[float, float, float, float, float, float]


class DigitalInputs(StrictModel):
    mask: int = Field(ge=0, le=DIGITAL_MASK)
    bits: int = Field(ge=0, le=DIGITAL_MASK)


class AnalogInput(StrictModel):
    channel: int = Field(ge=0, le=1)
    value: float | None = None
    domain: Literal["CURRENT", "VOLTAGE"] | None = None


class StateCommand(StrictModel):
    cmd: Literal["state"]
    id: Any = None


class SetCommand(StrictModel):
    cmd: Literal["set"]
    id: Any = None
    protective_stop: bool | None = None
    emergency_stop: bool | None = None
    robot_mode: Literal[tuple(m.name for m in RobotMode)] | None = None  # type: ignore[valid-type]
    digital_inputs: DigitalInputs | None = None
    analog_input: AnalogInput | None = None
    tcp_pose: Pose6 | None = None
    speed_fraction: float | None = Field(None, ge=0, le=1)


Command = TypeAdapter(Annotated[StateCommand | SetCommand, Field(discriminator="cmd")])


def handle(box: ControlBox, line: str) -> dict[str, Any]:
    """Execute one command line; the reply (never raises for a bad request)."""
    try:
        command = Command.validate_python(json.loads(line))
    except (ValueError, ValidationError) as exc:
        return {"ok": False, "error": f"bad command: {exc}".splitlines()[0]}
    reply: dict[str, Any] = {"ok": True} if command.id is None else {"ok": True, "id": command.id}
    box.sync()
    try:
        if isinstance(command, SetCommand):
            _apply(box, command)
        reply["state"] = box.snapshot()
    except (FluidsenseError, ValueError) as exc:
        reply.update(ok=False, error=str(exc))
    return reply


def _apply(box: ControlBox, c: SetCommand) -> None:
    m = box.model
    log.info("sim control: %s", c.model_dump(exclude_none=True))
    if c.emergency_stop is not None:
        m.emergency_stop = c.emergency_stop
    if c.protective_stop is not None:
        m.protective_stop = c.protective_stop
    if c.robot_mode is not None:
        m.robot_mode = RobotMode[c.robot_mode]
    if c.digital_inputs is not None:
        m.set_digital_inputs(c.digital_inputs.mask, c.digital_inputs.bits)
    if c.analog_input is not None:
        a = c.analog_input
        m.set_analog_input(a.channel, a.value, None if a.domain is None else AnalogDomain[a.domain])
    if c.tcp_pose is not None:
        place = getattr(m, "set_tcp_pose", None)  # KinematicModel has it; the contract does not
        if place is None:
            raise NotSupportedError(f"{type(m).__name__} cannot place the TCP")
        place(c.tcp_pose)
    if c.speed_fraction is not None:
        m.speed_fraction = c.speed_fraction
