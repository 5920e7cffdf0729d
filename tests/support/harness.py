"""Shared helpers: cell configs, virtual-time controllers on the simulated cell, daemon
subprocesses."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import socket
import subprocess
import sys
import time
import uuid
from pathlib import Path

import yaml
import zmq
from fluidsense.simulator.controlbox.process import SIMCELL_PORTS, free_loopback  # noqa: F401 - tests import them from here
from fluidsense.common.names import welcome_instance

REPO = Path(__file__).resolve().parents[2]
CONFIG = REPO / "config"
PROFILE = CONFIG / "profiles" / "pneunet-gripper.yaml"


def sim_config(tmp_path: Path, *, clock: str = "virtual", seed: int = 1, scene: dict | None = None,
               profile: dict | str | None = None, endpoints: tuple[str, str] | None = None,
               check: bool = True, **sections) -> Path:
    """The simulated cell the tests start from, written next to the test; ``sections``
    are overrides merged in and checked as support.configs.cell_config's are."""
    from support.configs import cell_config

    pub, cmd = endpoints or ipc_endpoints(tmp_path)
    base = {
        "driver": {"kind": "sim", "clock": clock, "rate_hz": 1000, "block_size": 10, "seed": seed,
                   "scene": scene or {"kind": "none"}},
        "profile": profile if profile is not None else str(PROFILE),
        "publisher": {"pub": pub, "cmd": cmd},
        # a daemon records (docs/recording.md): into the test's directory, never the repository
        "recording": {"dir": str(tmp_path / "runs"), "min_free_mb": 16},
    }
    return cell_config(tmp_path, base, check=check, **sections)


def write_cell(tmp_path: Path, data: dict) -> Path:
    """``data`` as it is, unchecked (a test's deliberately bad config)."""
    path = tmp_path / f"cell-{uuid.uuid4().hex[:6]}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def simcell_config(tmp_path: Path, kind: str, host: str, profile: str | None = None,
                   driver: dict | None = None, **sections) -> Path:
    """config/cell-{kind}-sim.yaml moved to ``host``, with ipc endpoints in the test's
    directory; ``driver`` replaces keys of its driver section (support.configs.cell_config)."""
    from support.configs import cell_config

    return cell_config(tmp_path, f"cell-{kind}-sim", profile=profile, driver={**(driver or {}), "host": host},
                       **sections)


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """A port nobody listens on now (the kernel's choice); a clash with another test in the
    moment before its user binds it fails that start loudly, never silently."""
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def free_simcell(tmp_path: Path, kind: str, profile: str | None = None, driver: dict | None = None, **sections):
    """``fluidsense simcell`` for a ``kind`` (ur, modbus) cell config on a free 127.0.0.x;
    yields (the box process, the cell config). The box must end cleanly."""
    from fluidsense.simulator.controlbox.process import EmulatorProcess

    for _ in range(5):
        cell = simcell_config(tmp_path, kind, free_loopback(SIMCELL_PORTS), profile, driver, **sections)
        box = EmulatorProcess(command=[sys.executable, "-m", "fluidsense", "simcell", "--config", str(cell)])
        try:
            box.start(timeout_s=30)
        except Exception:  # noqa: BLE001 - lost a race for the address: take the next one
            box.__exit__(None, None, None)  # a box that did not start in time is not left running
            if "cannot listen" in box.log():
                continue
            raise
        break
    else:
        raise RuntimeError("could not start fluidsense simcell on a free address")
    try:
        yield box, cell
    finally:
        killed = box.proc.poll() is not None and box.proc.returncode == -9
        code = box.stop()
        box.__exit__(None, None, None)
        assert killed or code == 0, box.log()
        assert "Traceback" not in box.log(), box.log()


@contextlib.contextmanager
def daemon_loop_priority(cfg):
    """The calling thread's loop at the priority a daemon's gets (``loop.rt_priority``,
    SCHED_FIFO when permitted) for the block, normal after it. A controller run in the test
    process against real-time peers stands for the daemon's: at normal priority, beside
    the suite's workers and busy loops, it measured this machine's scheduler instead of
    the product's loop."""
    from fluidsense.drivers.sampler import realtime

    realtime.set_loop_priority(cfg.loop.rt_priority)
    try:
        yield
    finally:
        realtime.release_loop_priority()


def ipc_endpoints(tmp_path: Path) -> tuple[str, str]:
    """ipc endpoints in a per-test directory: no port can clash between tests."""
    tag = uuid.uuid4().hex[:8]
    return f"ipc://{tmp_path}/pub-{tag}", f"ipc://{tmp_path}/cmd-{tag}"


def run(coro):
    return asyncio.run(coro)


class Daemon:
    """``fluidsense run`` in a subprocess, with a SUB and a REQ socket attached."""

    def __init__(self, config: Path, *extra: str, new_session: bool = False,
                 env: dict[str, str] | None = None):
        """``new_session``: the daemon and its helper processes get a process group of their own;
        ``env``: variables added to the daemon's environment."""
        cfg = yaml.safe_load(config.read_text())
        self.pub, self.cmd = cfg["publisher"]["pub"], cfg["publisher"]["cmd"]
        env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        self.proc = subprocess.Popen([sys.executable, "-m", "fluidsense", "run", "--config", str(config), *extra],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, cwd=REPO,
                                     start_new_session=new_session)
        self.ctx = zmq.Context()
        self.sub = self.ctx.socket(zmq.SUB)
        self.sub.setsockopt(zmq.LINGER, 0)
        self.sub.setsockopt(zmq.SUBSCRIBE, b"")
        self.sub.connect(self.pub)

    def wait_welcome(self, timeout_s: float = 30.0, ready: bool = True) -> None:
        """Block until the daemon has attached our subscription (its welcome frame) and,
        with ``ready``, has connected to its devices (status leaves ``connecting``: the
        daemon binds its sockets before it connects, and refuses cycles until then)."""
        while True:
            if not self.sub.poll(int(timeout_s * 1000)):
                raise AssertionError(f"no welcome from the daemon; stderr:\n{self.stderr_now()}")
            welcome = welcome_instance(self.sub.recv_multipart())
            if welcome is not None:
                self.instance = welcome  # the daemon's id, which its messages carry
                break
        while ready and self.request({"cmd": "status"}, timeout_s)["state"] == "connecting":
            pass  # each request waits for the daemon's answer: bounded by the daemon, not a sleep

    def request(self, payload, timeout_s: float = 30.0, raw: list[bytes] | None = None) -> dict:
        sock = self.ctx.socket(zmq.REQ)
        sock.setsockopt(zmq.LINGER, 0)
        sock.connect(self.cmd)
        try:
            if raw is not None:
                sock.send_multipart(raw)
            else:
                sock.send(json.dumps(payload).encode())
            if not sock.poll(int(timeout_s * 1000)):
                raise AssertionError(f"no reply to {payload!r}; stderr:\n{self.stderr_now()}")
            return json.loads(sock.recv())
        finally:
            sock.close()

    def next_message(self, topic: str | None = None, timeout_s: float = 30.0) -> tuple[str, dict]:
        while True:
            if not self.sub.poll(int(timeout_s * 1000)):
                raise AssertionError(f"no {topic or 'message'} within {timeout_s} s")
            frames = self.sub.recv_multipart()
            if len(frames) != 2:
                continue
            t, msg = frames[0].decode(), json.loads(frames[1])
            if topic is None or t == topic:
                return t, msg

    def wait_state(self, target: str, timeout_s: float = 60.0, box=None) -> dict:
        """The next ``state`` message into ``target``, within ``timeout_s`` in all. A cycle
        that ends first (a fault, a vent, back to idle) fails at once with its transitions,
        the daemon's status (its last cycle in it) and the box's log (``box``: an EmulatorProcess), where
        waiting on would only run into the test's timeout with none of it."""
        deadline = time.monotonic() + timeout_s
        seen: list[str] = []
        while (left := deadline - time.monotonic()) > 0:
            _, msg = self.next_message("state", timeout_s=left)
            if msg["to"] == target:
                return msg
            seen.append(f"{msg['from']} -> {msg['to']} ({msg.get('reason')})")
            if msg["to"] in ("fault", "vent", "idle"):
                status = self.request({"cmd": "status"}) if self.proc.poll() is None else "(daemon gone)"
                log = box.log()[-4000:] if box is not None else "(no box)"
                raise AssertionError(f"the cycle ended before {target}: {seen}\nstatus: {status}\nbox log:\n{log}")
        raise AssertionError(f"no state {target} within {timeout_s} s: {seen}")

    def stderr_now(self) -> str:
        if self.proc.poll() is None:
            return "(still running)"
        if self.proc.stderr.closed:  # after close(): what it read last
            return self.final_stderr
        return self.proc.stderr.read().decode(errors="replace")

    def close(self, timeout_s: float = 30.0) -> int:
        if self.proc.poll() is None:
            self.proc.terminate()
        try:
            rc = self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            rc = self.proc.wait()
        # the rest of its log, kept for stderr_now: an open pipe is a ResourceWarning when collected
        self.final_stderr = "" if self.proc.stderr.closed else self.stderr_now()
        for pipe in (self.proc.stdout, self.proc.stderr):
            pipe.close()
        self.sub.close()
        self.ctx.term()
        return rc


def profile_controller(profile: str, body, seed: int = 1):
    """Run ``body(controller)`` on a virtual simulated cell with a shipped profile."""
    from fluidsense.controller.config import CellConfig, load_profile
    from fluidsense.daemon import app
    from fluidsense.drivers.registry import SimDriverConfig

    prof = load_profile(CONFIG / "profiles" / f"{profile}.yaml")
    cfg = CellConfig(driver=SimDriverConfig(clock="virtual", seed=seed), profile=prof)

    async def main():
        async with app.controller(cfg) as ctrl:
            return await body(ctrl)

    return asyncio.run(main())


async def cycles_over(ctrl, scenes, n: int = 1, reference: bool = False):
    """Results of n cycles per scene (after an optional free-air reference)."""
    from fluidsense.common.scenes import EmptyScene

    if reference:
        await ctrl.scene.place(EmptyScene())
        await ctrl.run_cycle(store_reference=True)
    out = []
    for scene in scenes:
        await ctrl.scene.place(scene)
        for _ in range(n):
            res = await ctrl.run_cycle()
            assert res.ok, res.aborted
            out.append((scene, res, await ctrl.scene.truth()))
    return out
