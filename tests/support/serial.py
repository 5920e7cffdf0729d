"""The serial path's test equipment: ``python -m lab simserial`` (a board on a pty, fed by
the simulated cell: the firmware's host board, or the AVR image run by simavr) as a
subprocess, and a byte-level proxy that sits between the board's pty and the driver on a
second pty pair and damages chosen frames, as a bad cable would. Nothing here is mocked:
the driver reads a real tty, the board is the real C protocol code (on the AVR, the very
image a user flashes)."""

from __future__ import annotations

import json
import os
import select
import shutil
import subprocess
import sys
import threading
import tty
import uuid
from pathlib import Path
from typing import Any

import pytest
import yaml

from support.harness import CONFIG, REPO, ipc_endpoints

SAMPLE = 0x01  # the protocol's sample frame type (firmware/README.md)
#: what ``--board avr`` builds and runs on (Debian packages; ``make firmware-deps`` installs them)
AVR_PACKAGES = "gcc-avr avr-libc simavr libsimavr-dev"
AVR_READY = shutil.which("avr-gcc") is not None and Path("/usr/include/simavr/sim_avr.h").exists()
needs_avr = pytest.mark.skipif(not AVR_READY, reason=f"the AVR image in simavr needs Debian's {AVR_PACKAGES}")
#: the boards the tests run the serial driver against: the core compiled for Linux, the AVR image
BOARDS = [pytest.param("host"), pytest.param("avr", marks=needs_avr)]
#: the name each board gives in INFO
BOARD_NAMES = {"host": "host", "avr": "avr328p"}


def serial_config(tmp_path: Path, *, profile: str = "sorting-gripper-quick", port: Path | None = None,
                  driver: dict | None = None, control_port: int | None = None) -> Path:
    """A cell config for the serial driver with everything in ``tmp_path``."""
    cell = yaml.safe_load((CONFIG / "cell-serial-sim.yaml").read_text())
    pub, cmd = ipc_endpoints(tmp_path)
    d = {**cell["driver"], "port": str(port or tmp_path / "device.tty"), **(driver or {})}
    d.pop("sim_control_port", None)
    if control_port is not None:
        d["sim_control_port"] = control_port
    data = {"driver": d, "profile": str(CONFIG / "profiles" / f"{profile}.yaml"),
            "publisher": {"pub": pub, "cmd": cmd}, "log_level": "INFO",
            "recording": {"dir": str(tmp_path / "runs"), "min_free_mb": 16}}
    path = tmp_path / f"cell-serial-{uuid.uuid4().hex[:6]}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


class SimSerialProcess:
    """``python -m lab simserial`` in a child process; ``control`` talks to its sim control
    channel (stdin/stdout JSON lines)."""

    def __init__(self, config: Path, *extra: str):
        self.proc = subprocess.Popen([sys.executable, "-m", "lab", "simserial", "--config", str(config),
                                      *extra], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     cwd=REPO, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        self._lock = threading.Lock()
        line = self._line(60)
        if not line.startswith("ready "):
            raise AssertionError(f"simserial did not start: {line!r}\n{self.stderr()}")
        self.port = line.split(" ", 1)[1]

    def _line(self, timeout_s: float) -> str:
        if not select.select([self.proc.stdout], [], [], timeout_s)[0]:
            raise AssertionError(f"no line from simserial within {timeout_s} s")
        return self.proc.stdout.readline().decode().strip()

    def control(self, **request: Any) -> dict[str, Any]:
        with self._lock:
            self.proc.stdin.write((json.dumps(request) + "\n").encode())
            self.proc.stdin.flush()
            reply = json.loads(self._line(30))
        assert reply["ok"], reply
        return reply

    def stderr(self) -> str:
        if self.proc.poll() is None:
            return "(still running)"
        return self.proc.stderr.read().decode(errors="replace")

    def stop(self) -> tuple[int, dict[str, Any]]:
        """SIGTERM; its exit code and final statistics."""
        if self.proc.poll() is None:
            self.proc.terminate()
        out, err = self.proc.communicate(timeout=30)
        stats = [json.loads(x[6:]) for x in out.decode().splitlines() if x.startswith("stats ")]
        self.final_stderr = err.decode(errors="replace")
        return self.proc.returncode, stats[-1] if stats else {}


class Proxy:
    """Bytes between the board's pty (``device``) and the driver (which opens ``link``),
    on a second pty pair. Device -> host sample frames can be corrupted (one byte
    flipped), cut (one byte dropped) or held back altogether (a silent link)."""

    def __init__(self, device: str, link: Path):
        self.link = link
        self.master, slave = os.openpty()
        tty.setraw(slave)  # before any byte passes: a fresh pty echoes and translates
        self._slave = slave  # kept open: a master whose slave is closed reads EIO
        os.symlink(os.ttyname(slave), link)
        self.dev = os.open(device, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        tty.setraw(self.dev)
        os.set_blocking(self.master, False)
        self.corrupt = self.drop = 0  # sample frames still to damage
        self.damaged: list[str] = []
        self.holding = False
        self._pos = 0  # bytes since the last delimiter, device -> host
        self._frame_kind = -1
        self._damage_this = None
        self._lock = threading.Lock()
        self._stop_r, self._stop_w = os.pipe()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def damage(self, corrupt: int = 0, drop: int = 0) -> None:
        with self._lock:
            self.corrupt += corrupt
            self.drop += drop

    def pending(self) -> int:
        with self._lock:
            return self.corrupt + self.drop

    def hold(self, on: bool) -> None:
        self.holding = on

    def _filter(self, data: bytes) -> bytes:
        out = bytearray()
        with self._lock:
            for b in data:
                if b == 0:
                    self._pos, self._damage_this = 0, None
                    out.append(0)
                    continue
                self._pos += 1
                if self._pos == 2 and b == SAMPLE and self._damage_this is None:
                    if self.corrupt:
                        self.corrupt, self._damage_this = self.corrupt - 1, "corrupt"
                    elif self.drop:
                        self.drop, self._damage_this = self.drop - 1, "drop"
                if self._pos == 6 and self._damage_this is not None:  # inside the tick field
                    self.damaged.append(self._damage_this)
                    if self._damage_this == "drop":
                        continue
                    b ^= 0xAA if b == 0x55 else 0x55  # never 0: a zero would split the frame
                out.append(b)
        return bytes(out)

    def _filter_out(self, data: bytes) -> bytes:
        """Host -> device bytes, as they go on (a subclass may change them)."""
        return data

    def _run(self) -> None:
        while True:
            ready = select.select([self.dev, self.master, self._stop_r], [], [])[0]
            if self._stop_r in ready:
                return
            if self.dev in ready:
                try:
                    data = os.read(self.dev, 65536)
                except BlockingIOError:
                    data = b""
                except OSError:
                    return  # the board went away
                if data and not self.holding:
                    try:
                        os.write(self.master, self._filter(data))
                    except BlockingIOError:
                        pass  # nobody reads the link: as a full USB buffer, the bytes are lost
            if self.master in ready:
                try:
                    data = os.read(self.master, 65536)
                except (BlockingIOError, OSError):
                    data = b""
                if data and not self.holding:
                    os.write(self.dev, self._filter_out(data))

    def close(self) -> None:
        os.write(self._stop_w, b"x")
        self._thread.join(5)
        for fd in (self.master, self._slave, self.dev, self._stop_r, self._stop_w):
            os.close(fd)
        self.link.unlink(missing_ok=True)
