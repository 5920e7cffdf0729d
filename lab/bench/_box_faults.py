"""What ``bench faults --box-runs N`` adds: the faults software on the PC cannot vent,
measured against ``fluidsense simcell`` in real time (a daemon in its own process group,
the production drivers, the emulated UR box).

- ``daemon_killed``: SIGKILL to the daemon and its helper processes while the gripper is
  held. Latency: from the last box state read before the kill to the box's valve outputs
  at their safe levels (the box's own clock; the kill comes a few ms after that read).
- ``link_cut``: the box's network cable pulled while held. Latency: from the cut to the
  box venting by itself (its watchdog), on the box's clock.
- ``link_back``: the cable back in after a cut on a box without a watchdog. From the
  first output write the box receives after it (the service's first act on the new
  connection: the safe state) to the gripper below 1 kPa, on the box's clock.
- ``sigterm``: SIGTERM to the daemon's process group while the gripper is held (as
  systemd and Ctrl-C send it): from the last box state read before the signal to the
  box's outputs at their safe levels. (The daemon then closes its devices: ur_rtde's
  interfaces take about 0.5 s each to disconnect.)
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml
import zmq
from fluidsense.common.names import welcome_instance

PROFILE = "sorting-gripper-quick.yaml"
SAFE, INFLATED = 0b01, 0b11  # supply isolated (output 0 high), actuation valve (output 1) vented


def _cell(tmp: Path, kind: str, host: str, driver: dict[str, Any]) -> Path:
    from lab import REPO

    config = REPO / "config"
    data = yaml.safe_load((config / f"cell-{kind}-sim.yaml").read_text())
    data["driver"].update(driver, host=host, reconnect={"first_s": 0.2, "max_s": 0.5})
    data["profile"] = str(config / "profiles" / PROFILE)
    data["publisher"] = {"pub": f"ipc://{tmp}/pub", "cmd": f"ipc://{tmp}/cmd"}
    data["recording"] = {"enabled": False}
    data["log_level"] = "WARNING"
    path = tmp / f"cell-{kind}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@contextlib.contextmanager
def _simcell(cell: Path):
    from fluidsense.simulator.controlbox.process import EmulatorProcess

    box = EmulatorProcess(command=[sys.executable, "-m", "fluidsense", "simcell", "--config", str(cell)])
    box.start(timeout_s=30)
    try:
        yield box
    finally:
        box.stop()
        box.__exit__(None, None, None)


class _Daemon:
    def __init__(self, cell: Path):
        cfg = yaml.safe_load(cell.read_text())["publisher"]
        self.proc = subprocess.Popen([sys.executable, "-m", "fluidsense", "run", "--config", str(cell)],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        self.ctx = zmq.Context()
        self.sub = self.ctx.socket(zmq.SUB)
        self.sub.setsockopt(zmq.SUBSCRIBE, b"")
        self.sub.connect(cfg["pub"])
        self.cmd = cfg["cmd"]
        try:
            self._welcome(60)
            # the daemon binds its sockets before it reaches its devices and refuses cycles until then
            while self.request({"cmd": "status"})["state"] == "connecting":
                pass  # each request waits for the daemon's answer
        except BaseException:
            self.close()  # a daemon that never came up is not left running (the scenario's figure is its failure)
            raise

    def _welcome(self, timeout_s: float) -> None:
        """The one-frame welcome (``hello INSTANCE``) that says our subscription is attached."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.sub.poll(100) and welcome_instance(self.sub.recv_multipart()) is not None:
                return
        raise TimeoutError(f"no welcome from the daemon within {timeout_s:g} s")

    def request(self, payload: dict) -> dict:
        req = self.ctx.socket(zmq.REQ)
        req.setsockopt(zmq.LINGER, 0)
        req.connect(self.cmd)
        try:
            req.send(json.dumps(payload).encode())
            if not req.poll(30_000):
                raise TimeoutError(f"no reply to {payload['cmd']}")
            return json.loads(req.recv())
        finally:
            req.close()

    def _next(self, want, timeout_s: float) -> dict:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.sub.poll(100):
                frames = self.sub.recv_multipart()
                topic = frames[0].decode()
                msg = json.loads(frames[1]) if len(frames) == 2 else {}
                if want(topic, msg):
                    return msg
        raise TimeoutError("the daemon did not get there")

    def hold(self) -> None:
        reply = self.request({"cmd": "cycle"})
        if not reply.get("ok"):
            raise RuntimeError(f"cycle refused: {reply.get('error')}")
        self._next(lambda t, m: t == "state" and m.get("to") == "hold", 60)

    def close(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()
        self.sub.close()
        self.ctx.term()


def _after(state: dict, t: float, by: tuple[str, ...] | None = None) -> list:
    return [e for e in state["output_journal"] if e[0] > t and (by is None or e[2] in by)]


def _p_act_kpa(cell: Path, state: dict) -> float:
    from fluidsense.controller.config import load_cell_config

    s = load_cell_config(cell).driver.wiring.sensors["p_act"]
    return s.transfer.to_pa(state["analog_inputs"][s.analog_input]["value"]) / 1e3


def _one(kind: str, driver: dict[str, Any], scenario: str) -> float:
    from fluidsense.simulator.controlbox.process import free_loopback

    with tempfile.TemporaryDirectory(prefix="fluidsense-boxfaults-") as d:
        tmp = Path(d)
        cell = _cell(tmp, kind, free_loopback(), driver)
        with _simcell(cell) as box:
            daemon = _Daemon(cell)
            try:
                daemon.hold()
                before = box.state()
                if scenario == "daemon_killed":
                    os.killpg(daemon.proc.pid, signal.SIGKILL)
                    vented = box.wait_for(lambda s: s["digital_outputs"] & 0b11 == SAFE, 10, "vented")
                    return _after(vented, before["t"])[0][0] - before["t"]
                if scenario == "link_cut":
                    down = box.network(False)
                    vented = box.wait_for(lambda s: s["digital_outputs"] & 0b11 == SAFE, 10, "vented")
                    return _after(vented, down["t"], ("watchdog", "runstate"))[0][0] - down["t"]
                if scenario == "link_back":
                    box.network(False)
                    time.sleep(1.0)  # the cable stays out a while: the daemon latches its fault
                    up = box.network(True)
                    low = box.wait_for(lambda s: _p_act_kpa(cell, s) < 1.0, 60, "below 1 kPa")
                    return low["t"] - _after(low, up["t"])[0][0]
                if scenario == "sigterm":
                    os.killpg(daemon.proc.pid, signal.SIGTERM)
                    vented = box.wait_for(lambda s: s["digital_outputs"] & 0b11 == SAFE, 10, "vented")
                    daemon.proc.wait(60)
                    return _after(vented, before["t"])[0][0] - before["t"]
                raise ValueError(scenario)
            finally:
                daemon.close()


SCENARIOS = [
    ("daemon_killed", "ur", {}),
    ("daemon_killed", "modbus", {"arm": None}),
    ("link_cut", "ur", {}),
    ("link_cut", "modbus", {"arm": None}),
    ("link_back", "modbus", {"arm": None, "watchdog": None}),
    ("sigterm", "ur", {}),
    ("sigterm", "modbus", {"arm": None}),
]


def run_box_faults(runs: int) -> list[dict[str, Any]]:
    out = []
    for scenario, kind, driver in SCENARIOS:
        lat, failures = [], []
        for _ in range(runs):
            try:
                lat.append(_one(kind, driver, scenario))
            except Exception as exc:  # noqa: BLE001 - a failed run is a figure too
                failures.append(f"{type(exc).__name__}: {exc}"[:200])
        label = f"{kind}{'' if driver.get('arm', 1) is not None else ' (no arm)'}"
        out.append({"scenario": scenario, "driver": label, "runs": runs, "failed": len(failures),
                    "failures": failures[:3], "latency_s_median": float(np.median(lat)) if lat else None,
                    "latency_s_max": float(np.max(lat)) if lat else None})
    return out
