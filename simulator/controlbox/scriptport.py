"""Script port (30003): clients send URScript programs as text; a complete program
replaces the running one, a secondary program (``sec``) runs beside it. Only ur_rtde's
control script (urscript.py), fluidsense's box watchdog and run-state statements
(watchdog.py) are emulated; anything else is logged and ignored, and the robot keeps
doing what it did.

The real port also streams the robot state at 500 Hz to every client (the "realtime"
interface); that stream is not emulated, ur_rtde does not read it.
"""

from __future__ import annotations

import asyncio
import logging
import re

from fluidsense.simulator.controlbox.box import ControlBox, ProgramError
from fluidsense.simulator.controlbox.tcp import TcpServer
from fluidsense.simulator.controlbox.urscript import program_from_source, split_programs
from fluidsense.simulator.controlbox.watchdog import run_secondary

log = logging.getLogger(__name__)

#: a client sending more than this without a complete program is cut off
MAX_PENDING = 1 << 20
_PROGRAM_START = re.compile(r"^(def|sec)[ \t]", re.M)


class ScriptServer(TcpServer):
    def __init__(self, box: ControlBox, host: str, port: int):
        super().__init__(host, port)
        self.box = box

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        peer = writer.get_extra_info("peername")
        log.info("script client %s connected", peer)
        pending = ""
        try:
            while chunk := await reader.read(65536):
                pending += chunk.decode(errors="replace")
                pending = self._consume(pending)
                if len(pending) > MAX_PENDING:
                    log.warning("script client %s sent %d bytes without a complete program; closing",
                                peer, len(pending))
                    break
        finally:
            log.info("script client %s disconnected", peer)

    def _consume(self, pending: str) -> str:
        programs, rest = split_programs(pending)
        for name, source in programs:
            self._run(name, source)
        # bare statements (no def/sec) are a program of their own once a line is complete
        if rest.strip() and rest.endswith("\n") and not _PROGRAM_START.search(rest):
            self._run("<statements>", rest.strip())
            rest = ""
        return rest

    def _run(self, name: str, source: str) -> None:
        if source.lstrip().startswith("sec"):
            self.box.sync()
            if not run_secondary(self.box, name, source):
                log.warning("secondary program %s not run: only run-state statements are emulated", name)
            return
        try:
            program = program_from_source(name, source)
        except ProgramError as exc:
            log.error("script %s not run: %s", name, exc)
            return
        if program is None:
            first = source.strip().splitlines()[0][:80] if source.strip() else ""
            log.warning("script %s not run: only ur_rtde's control script is emulated (%r, %d bytes)",
                        name, first, len(source))
            return
        self.box.sync()
        self.box.run_program(program)
