"""Dashboard server (port 29999): a greeting line, then one reply line per command line.

Replies use PolyScope 5's wording, which clients match on ("Powering on", "Brake
releasing", "Starting program", ...). Loaded ``.urp`` programs are not interpreted: a
played program runs, doing nothing, until it is stopped.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable

from fluidsense.simulator.controlbox.box import ControlBox, IdleProgram, RuntimeState
from fluidsense.simulator.controlbox.model import RobotMode
from fluidsense.simulator.controlbox.tcp import TcpServer

log = logging.getLogger(__name__)

GREETING = "Connected: Universal Robots Dashboard Server"


class Dashboard:
    """Command interpreter, separate from the socket so it can be tested alone."""

    def __init__(self, box: ControlBox):
        self.box = box
        self.popup: str | None = None
        # (lower-case prefix, handler(argument) -> reply); longer prefixes first
        self._commands: list[tuple[str, Callable[[str], str]]] = sorted([
            ("polyscopeversion", lambda a: box.config.polyscope_version),
            ("version", lambda a: ".".join(map(str, box.config.version))),
            ("get serial number", lambda a: box.config.serial_number),
            ("get robot model", lambda a: box.config.robot_model),
            ("is in remote control", lambda a: "true" if box.config.remote_control else "false"),
            ("robotmode", lambda a: f"Robotmode: {box.model.robot_mode.name}"),
            ("safetymode", lambda a: f"Safetymode: {box.model.safety_mode.name}"),
            ("safetystatus", lambda a: f"Safetystatus: {box.model.safety_mode.name}"),
            ("running", lambda a: f"Program running: {'true' if box.program_running else 'false'}"),
            ("programstate", self._program_state),
            ("get loaded program", self._loaded),
            ("isprogramsaved", lambda a: f"true {self._program_name()}"),
            ("load installation", lambda a: f"Loading installation: {a}"),
            ("load", self._load),
            ("play", self._play),
            ("pause", self._pause),
            ("stop", self._stop),
            ("power on", self._power_on),
            ("power off", self._power_off),
            ("brake release", self._brake_release),
            ("unlock protective stop", self._unlock),
            ("close safety popup", lambda a: "closing safety popup"),
            ("restart safety", self._restart_safety),
            ("popup", self._popup),
            ("close popup", self._close_popup),
            ("addtolog", self._add_to_log),
            ("setuserrole", lambda a: f"Setting user role: {a}"),
            ("getuserrole", lambda a: "PROGRAMMER"),
            ("get operational mode", lambda a: "NONE"),
            ("set operational mode", lambda a: f"Operational mode '{a}' is set"),
            ("clear operational mode",
             lambda a: "No longer controlling the operational mode. Current operational mode: 'NONE'."),
            ("shutdown", self._shutdown),
        ], key=lambda item: -len(item[0]))

    def execute(self, line: str) -> str:
        """The reply to one command line (without the newline)."""
        command = line.strip()
        lower = command.lower()
        for prefix, handler in self._commands:
            if lower == prefix or lower.startswith(prefix + " "):
                reply = handler(command[len(prefix):].strip())
                log.debug("dashboard %r -> %r", command, reply)
                return reply
        log.warning("dashboard: could not understand %r", command)
        return f"could not understand: '{command}'"

    # -- programs ----------------------------------------------------------------------------
    def _program_name(self) -> str:
        if self.box.program is not None:
            return self.box.program.name
        return self.box.loaded_program or "<unnamed>"

    def _program_state(self, _: str) -> str:
        return f"{self.box.runtime_state.name} {self._program_name()}"

    def _loaded(self, _: str) -> str:
        loaded = self.box.loaded_program
        return f"Loaded program: {loaded}" if loaded else "No program loaded"

    def _load(self, path: str) -> str:
        if not path.endswith(".urp"):
            return f"File not found: {path}"
        if self.box.runtime_state != RuntimeState.STOPPED:
            self.box.stop_program("another program loaded")
        self.box.loaded_program = path
        log.info("dashboard: loaded %s (not interpreted)", path)
        return f"Loading program: {path}"

    def _play(self, _: str) -> str:
        box = self.box
        if box.runtime_state == RuntimeState.PAUSED:
            return "Starting program" if box.resume_program() else "Failed to execute: play"
        if box.runtime_state == RuntimeState.PLAYING:
            return "Starting program"
        if box.loaded_program is None or not box.run_program(IdleProgram(box.loaded_program)):
            return "Failed to execute: play"
        return "Starting program"

    def _pause(self, _: str) -> str:
        return "Pausing program" if self.box.pause_program() else "Failed to execute: pause"

    def _stop(self, _: str) -> str:
        # "Stopped" also when nothing runs: ur_rtde's constructor stops its old script
        # through the script itself and then sends "stop", and throws on anything else
        self.box.stop_program("dashboard stop")
        return "Stopped"

    # -- power and safety ----------------------------------------------------------------------
    def _power_on(self, _: str) -> str:
        model = self.box.model
        if model.robot_mode in (RobotMode.POWER_OFF, RobotMode.POWER_ON) and not model.emergency_stop:
            # a real arm boots for some seconds; here it is ready at once, brakes still on
            model.robot_mode = RobotMode.IDLE
        return "Powering on"

    def _power_off(self, _: str) -> str:
        self.box.stop_program("power off")
        self.box.model.robot_mode = RobotMode.POWER_OFF
        return "Powering off"

    def _brake_release(self, _: str) -> str:
        model = self.box.model
        if model.emergency_stop:
            return "Failed to execute: brake release"
        if model.robot_mode in (RobotMode.POWER_OFF, RobotMode.POWER_ON, RobotMode.IDLE):
            model.robot_mode = RobotMode.RUNNING  # UR powers on on the fly when needed
        return "Brake releasing"

    def _unlock(self, _: str) -> str:
        box = self.box
        if not box.model.protective_stop:
            return "Protective stop releasing"
        since = box.protective_since if box.protective_since is not None else box.sync()
        if box.sync() - since < box.config.unlock_delay_s:
            return ("Cannot unlock protective stop until 5s after occurrence. "
                    "Always inspect cause of protective stop before unlocking")
        box.model.protective_stop = False
        return "Protective stop releasing"

    def _restart_safety(self, _: str) -> str:
        self.box.stop_program("safety restart")
        self.box.model.protective_stop = False
        self.box.model.robot_mode = RobotMode.POWER_OFF
        return "Restarting safety"

    # -- operator interface ----------------------------------------------------------------------
    def _popup(self, text: str) -> str:
        self.popup = text
        return "showing popup"

    def _close_popup(self, _: str) -> str:
        self.popup = None
        return "closing popup"

    def _add_to_log(self, text: str) -> str:
        log.info("dashboard log: %s", text)
        return "Added log message"

    def _shutdown(self, _: str) -> str:
        if self.box.shutdown_requested is not None:
            self.box.shutdown_requested()
        return "Shutting down"


class DashboardServer(TcpServer):
    def __init__(self, box: ControlBox, host: str, port: int):
        super().__init__(host, port)
        self.dashboard = Dashboard(box)

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        peer = writer.get_extra_info("peername")
        log.info("dashboard client %s connected", peer)
        try:
            writer.write((GREETING + "\n").encode())
            while line := await reader.readline():
                command = line.decode(errors="replace").strip()
                if not command:
                    continue
                if command.lower() == "quit":
                    writer.write(b"Disconnected\n")
                    await writer.drain()
                    break
                writer.write((self.dashboard.execute(command) + "\n").encode())
                await writer.drain()
        finally:
            log.info("dashboard client %s disconnected", peer)
