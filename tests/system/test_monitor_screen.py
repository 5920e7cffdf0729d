"""``fluidsense monitor`` as a person sees it: a real daemon, the monitor in a real
pseudo-terminal, the screen read back from what it drew. And what `cmd` and `monitor`
say when nothing answers.

(Its in-process tests: tests/unit/test_monitor_screen.py.)
"""

from __future__ import annotations

import os
import pty
import re
import select
import subprocess
import sys
import time

import yaml
from support.harness import REPO, sim_config

ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")


def screens(raw: str) -> list[list[str]]:
    """Each redraw starts by homing the cursor: the frames, as lines without escapes."""
    return [[ANSI.sub("", line) for line in frame.split("\n")] for frame in raw.split("\x1b[H")[1:]]


def test_monitor_in_a_terminal_shows_state_pressure_and_the_last_result(tmp_path, daemon_factory):
    cfg = sim_config(tmp_path, clock="virtual")  # a cycle in moments; pressure flows while it runs
    d = daemon_factory(cfg)
    d.wait_welcome()
    master, slave = pty.openpty()
    mon = subprocess.Popen([sys.executable, "-m", "fluidsense", "monitor", "--config", str(cfg)], cwd=REPO,
                           stdin=slave, stdout=slave, stderr=subprocess.PIPE, env={**os.environ, "TERM": "xterm"})
    os.close(slave)
    raw = ""
    try:
        def read_until(pred, timeout_s=60.0):
            nonlocal raw
            deadline = time.monotonic() + timeout_s
            while time.monotonic() < deadline:
                if select.select([master], [], [], 1.0)[0]:
                    raw += os.read(master, 65536).decode(errors="replace")
                    frames = screens(raw)
                    if len(frames) > 1 and pred("\n".join(frames[-2])):  # the last complete frame
                        return "\n".join(frames[-2])
            raise AssertionError(f"the screen never showed it; last frames:\n{raw[-3000:]}")

        read_until(lambda s: "state IDLE" in s and "valves (device):" in s and "none yet" in s)
        assert d.request({"cmd": "cycle"})["ok"]
        screen = read_until(lambda s: "cycle 1:" in s and "P_eq" in s)
        first = d.instance
        assert f"daemon {first}" in screen, screen
        # the daemon stops: the screen says so, shows no state, names the whole endpoint
        assert d.request({"cmd": "shutdown"})["ok"] and d.proc.wait(30) == 0
        _, cmd = ipc_endpoints_of(cfg)
        gone = read_until(lambda s: f"valves: no status from {cmd} (" in s)
        assert f"the daemon {first}: stopped; its state is not known" in gone, gone
        assert "state IDLE" not in gone and "last results (of the daemon that is gone):" in gone, gone
        assert "(not answering status within 0.5 s)" in gone, gone
        # another daemon on the same endpoints: its own state only, nothing of the old one's
        again = daemon_factory(cfg)
        again.wait_welcome()
        fresh = read_until(lambda s: f"daemon {again.instance}" in s and "state IDLE" in s)
        assert again.instance != first and first not in fresh, fresh
        assert "cycle 1:" not in fresh and "none yet" in fresh and "cycle 0" in fresh, fresh
    finally:
        mon.terminate()
        mon.wait(30)
        os.close(master)
    assert re.search(r"cycle 1: P_eq \d+\.\d{3} ± \d+\.\d{3} kPa", screen), screen
    assert re.search(r"p_act\s+-?\d+\.\d\d kPa", screen), screen  # the trace of the cycle
    assert "state IDLE" in screen and "valves (device):" in screen and "closed" in screen, screen
    with mon.stderr:
        assert "Traceback" not in mon.stderr.read().decode()


def ipc_endpoints_of(cfg) -> tuple[str, str]:
    data = yaml.safe_load(cfg.read_text())
    return data["publisher"]["pub"], data["publisher"]["cmd"]


def test_cmd_and_monitor_name_the_endpoint_when_nothing_answers(tmp_path):
    nobody = f"ipc://{tmp_path}/nobody"
    out = subprocess.run([sys.executable, "-m", "fluidsense", "cmd", "status", "--endpoint", nobody,
                          "--timeout", "0.2"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert out.returncode == 3
    assert nobody in out.stderr and "may not be running" in out.stderr and "Traceback" not in out.stderr
    out = subprocess.run([sys.executable, "-m", "fluidsense", "monitor", "--log", "--endpoint", nobody,
                          "--timeout", "0.2"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert out.returncode == 3  # a timeout, as docs/cli.md says (it was 1, a daemon failure's code)
    assert nobody in out.stderr and "may not be running" in out.stderr
