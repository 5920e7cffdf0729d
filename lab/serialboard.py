"""A simulated serial device (``python -m lab simserial``): the firmware's host board (the C
program of firmware/boards/host, behind a pseudo-terminal) with the simulated cell on its
pins. It lives with the CLI, not in drivers/: the serial driver is a production driver
and never imports the simulator.

The board process owns the pty and the protocol; this process owns the plant. They talk
over the board's stdin/stdout in fixed 32-byte records (firmware/boards/host/plant_link.h):
at every tick the board reports its outputs and asks for the analog inputs at the next
tick's deadline; the plant steps the simulated cell to that time (its clock is the board's
CLOCK_MONOTONIC deadlines) and answers with ADC counts through each sensor's transfer
function. Output changes arrive as they happen and move the plant's valves and
regulator at that instant (the plant has computed one tick ahead: a command may land up
to one period late, beside the valves' 12 ms switching delay).

The sim control channel (JSON lines on stdin, and on TCP ``driver.sim_control_port``)
answers ``state`` (valves, outputs, the board's watchdog vents, pressures), ``scene``,
``truth`` and ``reset`` (the board resets as a brown-out would).
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import signal
import struct
import subprocess
import sys
from pathlib import Path
from typing import Any

from fluidsense.common.hardware import Hardware
from fluidsense.common.scenes import Scene
from fluidsense.common.units import KPA
from fluidsense.drivers.config import SimDriverConfig
from fluidsense.drivers.serial.config import SerialDriverConfig
from fluidsense.simulator.cell import SimulatedCell
from pydantic import TypeAdapter, ValidationError

from lab import REPO

log = logging.getLogger(__name__)

FIRMWARE = REPO / "firmware"
BOARD = FIRMWARE / "build" / "host" / "fsboard-host"
REC = struct.Struct("<BBBBHHIIQQ")  # board -> plant
ADC = struct.Struct("<BBHIQ8H")  # plant -> board
TICK, OUTPUTS, VENT, RESET = 1, 2, 3, 4
REC_ADC, REC_DO_RESET = 1, 2
_SCENE = TypeAdapter(Scene)


def build_board() -> Path:
    """The host board image, built by ``make -C firmware host`` when missing or stale."""
    out = subprocess.run(["make", "-s", "-C", str(FIRMWARE), "host"], capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"building the host board failed (needs make and a C compiler):\n{out.stderr}")
    return BOARD


class SerialPlant:
    """The simulated cell wired to the board's pins as ``driver.wiring`` says."""

    def __init__(self, hw: Hardware, cfg: SerialDriverConfig, sim: SimDriverConfig):
        self.cell = SimulatedCell(sim, hw)
        self.cfg = cfg
        self.t0_ns: int | None = None
        self.full = 2 ** cfg.adc.bits - 1
        self.inputs = {s.adc: (name, s.transfer) for name, s in cfg.wiring.sensors.items()}
        self.latest = {name: 0.0 for name in self.cell.channels}
        self.outputs = -1
        self.aout = (-1, -1)
        self.flags = self.session = 0
        self.vents: list[dict[str, Any]] = []
        self.resets = 0
        self.ticks = 0

    def now(self, t_ns: int) -> float:
        return (t_ns - self.t0_ns) / 1e9

    def on_record(self, rec: bytes) -> bytes:
        """One record from the board; the reply (possibly empty)."""
        kind, outputs, flags, session, a0, a1, tick, extra, t_ns, next_ns = REC.unpack(rec)
        if self.t0_ns is None:
            self.t0_ns = t_ns
        self.flags, self.session = flags, session
        t = max(0.0, self.now(t_ns))
        if kind in (TICK, OUTPUTS, RESET):
            self._outputs(outputs, (a0, a1), t)
        if kind == VENT:
            self.vents.append({"tick": tick, "last_heartbeat_tick": extra, "t_s": t})
            log.warning("the board vented by its heartbeat watchdog at tick %d (last heartbeat: tick %d)", tick, extra)
        elif kind == RESET:
            self.resets += 1
        if kind != TICK:
            return b""
        self.ticks += tick != 0xFFFFFFFF  # not the request for the first tick after a (re)start
        return ADC.pack(REC_ADC, 8, 0, 0, next_ns, *self._counts(self.now(next_ns)))

    def _outputs(self, bits: int, aout: tuple[int, int], t: float) -> None:
        if bits != self.outputs:
            for valve, w in self.cfg.wiring.valves.items():
                open_ = bool(bits >> w.output & 1) == w.open_when_energised
                if self.outputs < 0 or bool(self.outputs >> w.output & 1) != bool(bits >> w.output & 1):
                    self.cell.command_valve(valve, open_, t)
            self.outputs = bits
        reg = self.cfg.wiring.regulator
        if reg is not None and aout[reg.analog_output] != self.aout[reg.analog_output]:
            gain, offset = self.cfg.analog_out.raw_affine(reg.input)
            self.cell.command_setpoint(reg.to_pa(gain * aout[reg.analog_output] + offset), t)
        self.aout = aout

    def _counts(self, t: float) -> list[int]:
        due = int(t * self.cell.cfg.rate_hz + 1e-9) + 1 - self.cell.k_next  # samples at or before t
        if due > 0:
            _, values = self.cell.next_block(due)
            self.latest = dict(zip(self.cell.channels, values[-1].tolist()))
        counts = [0] * 8
        lsb = self.cfg.adc.reference_v / (self.full + 1)
        for ch, (name, transfer) in self.inputs.items():
            volts = transfer.to_signal(self.latest[name])
            counts[ch] = min(self.full, max(0, int(volts // lsb)))  # a SAR ADC truncates
        return counts

    def state(self) -> dict[str, Any]:
        true = self.cell.true_values() if self.cell.k_next else {}
        return {"t_s": self.cell.t_last, "valves": dict(self.cell.outputs), "outputs": self.outputs,
                "session": self.session, "armed": bool(self.flags & 1), "vented": bool(self.flags & 2),
                "streaming": bool(self.flags & 0x80), "vents": self.vents, "resets": self.resets, "ticks": self.ticks,
                "pressures_kpa": {k: v / KPA for k, v in true.items()}}


class SimSerial:
    """The board process and the plant, with the sim control channel."""

    def __init__(self, plant: SerialPlant, board_argv: list[str]):
        self.plant = plant
        self.argv = board_argv
        self.proc: subprocess.Popen[bytes] | None = None
        self.ready = asyncio.Event()
        self.done = asyncio.Event()
        self.board_stats: dict[str, Any] | None = None
        self._buf = b""
        self._err = b""

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        self.proc = subprocess.Popen(self.argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     start_new_session=True)
        for f in (self.proc.stdout, self.proc.stderr):
            os.set_blocking(f.fileno(), False)
        loop.add_reader(self.proc.stdout.fileno(), self._records)
        loop.add_reader(self.proc.stderr.fileno(), self._stderr)

    def _records(self) -> None:
        try:
            data = os.read(self.proc.stdout.fileno(), 1 << 16)
        except BlockingIOError:
            return
        if not data:
            asyncio.get_running_loop().remove_reader(self.proc.stdout.fileno())
            self.done.set()
            return
        buf = self._buf + data
        n = len(buf) // REC.size * REC.size
        replies = b"".join(self.plant.on_record(buf[i:i + REC.size]) for i in range(0, n, REC.size))
        self._buf = buf[n:]
        if replies:
            try:
                os.write(self.proc.stdin.fileno(), replies)
            except (BrokenPipeError, BlockingIOError):
                pass  # the board is gone, or its input is full: it samples its newest values

    def _stderr(self) -> None:
        try:
            data = os.read(self.proc.stderr.fileno(), 1 << 16)
        except BlockingIOError:
            return
        if not data:
            asyncio.get_running_loop().remove_reader(self.proc.stderr.fileno())
            return
        *lines, self._err = (self._err + data).split(b"\n")
        for raw in lines:
            line = raw.decode(errors="replace")
            if line.startswith("ready "):
                self.ready.set()
            elif line.startswith("stats "):
                self.board_stats = json.loads(line[6:])
            else:
                print(line, file=sys.stderr, flush=True)

    def reset_board(self) -> None:
        os.write(self.proc.stdin.fileno(), ADC.pack(REC_DO_RESET, 0, 0, 0, 0, *[0] * 8))

    async def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        await asyncio.wait_for(self.done.wait(), 10)
        code = await asyncio.get_running_loop().run_in_executor(None, self.proc.wait)
        await asyncio.sleep(0)  # the stats line's reader callback
        self._stderr()
        return code

    def control(self, line: bytes) -> dict[str, Any]:
        """One sim control request -> its reply, after every record the board has written
        (it reports an output change before it acknowledges the command)."""
        self._records()
        try:
            req = json.loads(line)
            cmd = req.get("cmd") if isinstance(req, dict) else None
            if cmd == "state":
                return {"ok": True, **self.plant.state(), "board_pid": self.proc.pid}
            if cmd == "scene":
                self.plant.cell.set_scene(_SCENE.validate_python(req.get("scene")), self.plant.cell.t_last)
                return {"ok": True}
            if cmd == "truth":
                return {"ok": True, "truth": self.plant.cell.truth()}
            if cmd == "reset":
                self.reset_board()
                return {"ok": True}
            return {"ok": False, "error": f"unknown command {cmd!r}; known: state, scene, truth, reset"}
        except (ValueError, ValidationError) as exc:
            return {"ok": False, "error": str(exc).splitlines()[0]}
