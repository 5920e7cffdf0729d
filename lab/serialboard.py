"""A simulated serial device (``python -m lab simserial``): a board process behind a
pseudo-terminal with the simulated cell on its pins. Two boards (``--board``):

- ``host``: the firmware's core compiled for Linux (firmware/boards/host), sampling on a
  timerfd;
- ``avr``: the AVR image itself (build/avr/fluidsense.elf, what a user flashes) executed
  cycle by cycle by simavr as an ATmega328P at 16 MHz (firmware/boards/simavr).

It lives with the studies, not in drivers/: the serial driver is a production driver and
never imports the simulator.

The board process owns the pty and the protocol; this process owns the plant. They talk
over the board's stdin/stdout in fixed 32-byte records (firmware/boards/pc/plant_link.h):
at every tick the board reports its outputs and asks for the analog inputs at the next
tick's time; the plant steps the simulated cell to that time (the host board's
CLOCK_MONOTONIC deadlines, the AVR's cycles mapped onto that clock) and answers with ADC
counts through each sensor's transfer function. Output changes arrive as they happen and
move the plant's valves and regulator at that instant (the plant has computed one tick
ahead: a command may land up to one period late, beside the valves' 12 ms switching delay).

The sim control channel (JSON lines on stdin, and on TCP ``driver.sim_control_port``)
answers ``state`` (valves, outputs, the board's watchdog vents, resets, pressures),
``scene``, ``truth``, ``reset`` (the board resets as its reset pin would) and, on the AVR,
``stall`` (the firmware's main loop stops; its hardware watchdog must reset it).
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
from fluidsense.drivers.registry import SimDriverConfig
from fluidsense.drivers.serial.config import SerialDriverConfig
from fluidsense.simulator.cell import SimulatedCell
from pydantic import TypeAdapter, ValidationError

from lab import REPO

log = logging.getLogger(__name__)

FIRMWARE = REPO / "firmware"
BUILD = FIRMWARE / "build"
#: the board programs and the make target that builds each (firmware/Makefile)
BOARDS = {"host": (BUILD / "host" / "fsboard-host", "host"), "avr": (BUILD / "sim" / "fsboard-simavr", "sim")}
AVR_IMAGE = BUILD / "avr" / "fluidsense.elf"
REC = struct.Struct("<BBBBHHIIQQ")  # board -> plant
ADC = struct.Struct("<BBHIQ8H")  # plant -> board
TICK, OUTPUTS, VENT, RESET, STATE = 1, 2, 3, 4, 5  # STATE: flags or session only (plant_link.h)
REC_ADC, REC_DO_RESET, REC_DO_STALL = 1, 2, 3
RESET_CAUSES = {0: "power-on", 1: "external", 2: "brown-out", 3: "watchdog", 4: "software"}
_SCENE = TypeAdapter(Scene)


def build_board(kind: str = "host") -> Path:
    """The board program, built by make when missing or stale (``avr``: the AVR image and
    the simavr harness, which need Debian's gcc-avr, avr-libc, simavr and libsimavr-dev)."""
    path, target = BOARDS[kind]
    out = subprocess.run(["make", "-s", "-C", str(FIRMWARE), target], capture_output=True, text=True)
    if out.returncode != 0:
        needs = "make and a C compiler" if kind == "host" else \
            "Debian's gcc-avr, avr-libc, simavr and libsimavr-dev (make firmware-deps)"
        raise RuntimeError(f"building the {kind} board failed (needs {needs}):\n{out.stderr}")
    return path


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
        self.reset_causes: list[str] = []
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
            # the simulated AVR also measures, in its own cycles, the heartbeat frame's last byte to the pins
            self.vents.append({"tick": tick, "last_heartbeat_tick": extra, "t_s": t,
                               "since_heartbeat_s": next_ns / 1e9 if next_ns else None})
            log.warning("the board vented by its heartbeat watchdog at tick %d (last heartbeat: tick %d)", tick, extra)
        elif kind == RESET and extra != 0:  # not the simulated AVR's first power-on
            self.resets += 1
            self.reset_causes.append(RESET_CAUSES.get(extra, f"cause {extra}"))
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
                "streaming": bool(self.flags & 0x80), "vents": self.vents, "resets": self.resets, "reset_causes": self.reset_causes, "ticks": self.ticks,
                "pressures_kpa": {k: v / KPA for k, v in true.items()}}


class SimSerial:
    """The board process and the plant, with the sim control channel."""

    def __init__(self, plant: SerialPlant, board_argv: list[str], board: str = "host"):
        self.plant = plant
        self.board = board
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

    def stall_board(self) -> None:
        os.write(self.proc.stdin.fileno(), ADC.pack(REC_DO_STALL, 0, 0, 0, 0, *[0] * 8))

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
                return {"ok": True, **self.plant.state(), "board": self.board, "board_pid": self.proc.pid}
            if cmd == "scene":
                self.plant.cell.set_scene(_SCENE.validate_python(req.get("scene")), self.plant.cell.t_last)
                return {"ok": True}
            if cmd == "truth":
                return {"ok": True, "truth": self.plant.cell.truth()}
            if cmd == "reset":
                self.reset_board()
                return {"ok": True}
            if cmd == "stall" and self.board == "avr":
                self.stall_board()
                return {"ok": True}
            known = "state, scene, truth, reset" + (", stall" if self.board == "avr" else "")
            return {"ok": False, "error": f"unknown command {cmd!r}; known: {known}"}
        except (ValueError, ValidationError) as exc:
            return {"ok": False, "error": str(exc).splitlines()[0]}
