"""The emulator's own control channel: what a person does at a real cell (press the
e-stop, wire a signal to an input, read what the arm did), as JSON lines.

The process entry reads one JSON object per line on stdin and answers one JSON object
per line on stdout: ``{"cmd": "state"}`` returns a snapshot of the model;
``{"cmd": "set", ...}`` changes what is given, e.g.
``{"cmd": "set", "protective_stop": true}`` or
``{"cmd": "set", "analog_input": {"channel": 0, "value": 4.5, "domain": "VOLTAGE"}}``.
Replies are ``{"ok": true, ...}`` or ``{"ok": false, "error": "..."}``, with the
request's ``id`` echoed when it has one. This is not part of the UR control box.

A box backed by the simulated plant (``fluidsense simcell``) also answers ``scene``
(place an object), ``world`` (lay out slots and objects for an arm), ``truth`` (what a
bench instrument would read), ``inject`` / ``clear_faults`` (fault injection) and
``command_lag`` (valve commands reach the valves late, as from a busy PC) and ``valve_log``
(the latest valve changes: when each was commanded and when the valve moved, box time). Every
box answers ``network`` (pull the cable), ``rtde_lag`` (slow RTDE streams arrive late) and
``lie`` (say on the wire what cannot be true: lies.py). The
same commands are served over TCP (one JSON object per line each way) when the cell
config names a ``sim_control_port``: that is how a daemon's simulated task lays out its
objects and scores itself.
"""

from __future__ import annotations

import asyncio
import json
import logging
from typing import Annotated, Any, Literal

from fluidsense.common.errors import FluidsenseError, NotSupportedError
from fluidsense.common.models import StrictModel
from fluidsense.common.scenes import Scene
from fluidsense.common.world import WorldSpec
from fluidsense.simulator.controlbox.box import ControlBox
from fluidsense.simulator.controlbox.lies import KINDS
from fluidsense.simulator.controlbox.model import DIGITAL_MASK, AnalogDomain, RobotMode
from pydantic import Field, TypeAdapter, ValidationError

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


class SceneCommand(StrictModel):
    cmd: Literal["scene"]
    id: Any = None
    scene: Scene


class WorldCommand(StrictModel):
    cmd: Literal["world"]
    id: Any = None
    world: WorldSpec


class TruthCommand(StrictModel):
    cmd: Literal["truth"]
    id: Any = None


class InjectCommand(StrictModel):
    cmd: Literal["inject"]
    id: Any = None
    fault: str = Field(min_length=1, max_length=40)
    after_s: float = Field(0.0, ge=0, le=3600)


class CommandLagCommand(StrictModel):
    """Every valve command reaches its valve ``lag_s`` late (a PC busy between deciding a
    command and sending it: the latency a polled driver cannot see); 0 ends it."""

    cmd: Literal["command_lag"]
    id: Any = None
    lag_s: float = Field(ge=0, le=1)


class ValveLogCommand(StrictModel):
    """The latest valve changes (up to 64), oldest first: ``valve``, ``open``, when the box
    applied the command (``commanded_s``) and when the valve moved (``effective_s``, after
    its switching delay and any ``command_lag``), on the box's clock."""

    cmd: Literal["valve_log"]
    id: Any = None


class ClearFaultsCommand(StrictModel):
    cmd: Literal["clear_faults"]
    id: Any = None


class NetworkCommand(StrictModel):
    """The box's network cable: ``up: false`` closes every robot port and every connection
    to them (a pulled cable), the box itself runs on; ``up: true`` listens again."""

    cmd: Literal["network"]
    id: Any = None
    up: bool


class RtdeLagCommand(StrictModel):
    """RTDE output streams at ``max_hz`` or slower reach their clients ``lag_s`` late (a
    client's receive thread starved on a busy PC); ``lag_s: 0`` ends it."""

    cmd: Literal["rtde_lag"]
    id: Any = None
    max_hz: float = Field(gt=0, le=1000)
    lag_s: float = Field(ge=0, le=10)


class LieCommand(StrictModel):
    """The box says what cannot be true in ``count`` packages or replies (or, for a
    ``freeze``, I/O cycles; lies.py names each ``kind``): a hostile box for the driver's
    checks. ``on_output``: the lie begins ``delay_s`` after that digital output next turns on."""

    cmd: Literal["lie"]
    id: Any = None
    kind: Literal[KINDS]  # type: ignore[valid-type]
    count: int = Field(gt=0, le=1_000_000)
    on_output: int | None = Field(None, ge=0, le=17)
    delay_s: float = Field(0.0, ge=0, le=60)


_PLANT = (SceneCommand, WorldCommand, TruthCommand, InjectCommand, ClearFaultsCommand, CommandLagCommand,
          ValveLogCommand)
SimRequest = TypeAdapter(Annotated[StateCommand | SetCommand | SceneCommand | WorldCommand | TruthCommand
                                | InjectCommand | ClearFaultsCommand | CommandLagCommand | ValveLogCommand
                                | NetworkCommand
                                | RtdeLagCommand
                                | LieCommand,
                                Field(discriminator="cmd")])


def handle(box: ControlBox, line: str) -> dict[str, Any]:
    """Execute one command line; the reply (never raises for a bad request)."""
    try:
        command = SimRequest.validate_python(json.loads(line))
    except (ValueError, ValidationError) as exc:
        return {"ok": False, "error": f"bad command: {exc}".splitlines()[0]}
    reply: dict[str, Any] = {"ok": True} if command.id is None else {"ok": True, "id": command.id}
    box.sync()
    try:
        if isinstance(command, _PLANT):
            reply.update(_plant(box, command))
            return reply
        if isinstance(command, SetCommand):
            _apply(box, command)
            box.latch_inputs()
        elif isinstance(command, NetworkCommand):
            if box.network_requested is None:
                raise NotSupportedError("this box's network cannot be pulled")
            box.network_requested(command.up)
        elif isinstance(command, RtdeLagCommand):
            box.rtde_lag = (command.max_hz, command.lag_s)
            log.info("sim control: RTDE streams at %g Hz or slower %g s late", command.max_hz, command.lag_s)
        elif isinstance(command, LieCommand):
            box.lies.tell(command.kind, box.model.t, command.count, command.on_output, command.delay_s)
        reply["state"] = box.snapshot()
        reply["lies"] = box.lies.state()
    except (FluidsenseError, ValueError) as exc:
        reply.update(ok=False, error=str(exc))
    return reply


def _plant(box: ControlBox, c: StrictModel) -> dict[str, Any]:
    m = box.model
    if not hasattr(m, "truth"):
        raise NotSupportedError(f"{type(m).__name__} has no simulated plant (run fluidsense simcell)")
    if isinstance(c, SceneCommand):
        m.set_scene(c.scene)
    elif isinstance(c, WorldCommand):
        m.set_world(c.world)
    elif isinstance(c, InjectCommand):
        m.inject(c.fault, c.after_s)
    elif isinstance(c, ClearFaultsCommand):
        m.clear_faults()
    elif isinstance(c, CommandLagCommand):
        m.cell.command_lag_s = c.lag_s
    elif isinstance(c, ValveLogCommand):
        return {"valves": [{"valve": v, "open": o, "commanded_s": tc, "effective_s": te}
                           for v, o, tc, te in m.cell.valve_log]}
    if not isinstance(c, TruthCommand):
        log.info("sim control: %s", c.cmd)
    return {"truth": m.truth()}


async def serve_tcp(box: ControlBox, host: str, port: int) -> asyncio.Server:
    """The sim control channel on ``host:port``: one JSON request per line, one reply per line."""

    async def client(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            while line := await reader.readline():
                if line.strip():
                    writer.write((json.dumps(handle(box, line.decode(errors="replace")), default=float)
                                  + "\n").encode())
                    await writer.drain()
        except (ConnectionError, asyncio.IncompleteReadError):
            pass
        finally:
            writer.close()

    return await asyncio.start_server(client, host, port, limit=1 << 20)


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
