"""The command line as a process: what only a real ``python -m fluidsense`` shows (its
imports, a closed pipe, exit codes against a real daemon or none over ZeroMQ). What each
command prints and returns in this process is tests/unit/test_cli.py."""

from __future__ import annotations

import json
import subprocess
import sys

from support.harness import REPO


def test_cmd_without_a_daemon_times_out_with_a_clear_error(tmp_path):
    out = subprocess.run([sys.executable, "-m", "fluidsense", "cmd", "status", "--endpoint",
                          f"ipc://{tmp_path}/nobody", "--timeout", "0.2"], cwd=REPO,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 3
    assert "no reply" in out.stderr


def test_building_the_command_line_loads_none_of_the_heavy_libraries():
    """`fluidsense --help` and every command's parser come up without numpy, pydantic,
    scipy, pyzmq or the configs: those load in the command that uses them (the CLI once took
    4 s to say its help on a busy machine; docs/cli.md has the measurement)."""
    probe = ("import sys, fluidsense.cli as c; p = c.build_parser(); p.format_help(); "
             "print(sorted(m for m in ('numpy', 'pydantic', 'scipy', 'zmq', 'yaml', 'tqdm', 'matplotlib', "
             "'fluidsense.controller.config', 'fluidsense.daemon.app') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", probe], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_output_to_a_closed_pipe_ends_quietly():
    """`fluidsense cmd status | head -1`: the reader went away before the output came (here
    before the demo prints its result): no traceback, exit 0."""
    demo = subprocess.Popen([sys.executable, "-m", "fluidsense", "demo", "--json", "--cycles", "3"], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    demo.stdout.close()  # gone before the demo has anything to say
    with demo.stderr:
        err = demo.stderr.read().decode()
    assert demo.wait(120) == 0
    assert "Traceback" not in err and "BrokenPipe" not in err, err


def _documented_exits() -> dict[tuple[str, str], int]:
    """docs/cli.md's per-command exit table: (command, case) -> code."""
    import re

    text = (REPO / "docs" / "cli.md").read_text()
    rows = re.findall(r"^\| `fluidsense (\w+)[^`]*` \| ([^|]+?) \| (\d+) \|$", text, flags=re.M)
    return {(cmd, case): int(code) for cmd, case, code in rows}


def test_cmd_and_monitor_exit_as_documented(tmp_path):
    """The codes docs/cli.md gives, read from it, against a running daemon (an error reply)
    and against nobody (nothing heard, no reply)."""
    from support.harness import Daemon, sim_config

    doc = _documented_exits()
    error_reply = doc[("cmd", "the daemon answers the request with an error (a refused command)")]
    # the row may go on to name more cases with the same code (cmd --wait's missing result)
    (no_reply,) = {code for (cmd, case), code in doc.items()
                   if cmd == "cmd" and case.startswith("no reply within `--timeout`")}
    unheard = doc[("monitor", "nothing heard within S")]
    cell = sim_config(tmp_path, clock="realtime")
    daemon = Daemon(cell)
    try:
        daemon.wait_welcome()
        refused = subprocess.run([sys.executable, "-m", "fluidsense", "cmd", '{"cmd": "explode"}', "--config",
                                  str(cell)], cwd=REPO, capture_output=True, text=True, timeout=60)
    finally:
        assert daemon.close() == 0
    assert refused.returncode == error_reply, refused.stdout + refused.stderr
    assert "unknown command" in refused.stdout + refused.stderr
    nobody = f"ipc://{tmp_path}/nobody"
    silent = subprocess.run([sys.executable, "-m", "fluidsense", "cmd", "status", "--endpoint", nobody, "--timeout",
                             "0.2"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert silent.returncode == no_reply, silent.stderr
    unheard_run = subprocess.run([sys.executable, "-m", "fluidsense", "monitor", "--endpoint", nobody, "--timeout",
                                  "0.3"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert unheard_run.returncode == unheard, unheard_run.stderr
    assert "nothing heard" in unheard_run.stderr


def test_cmd_wait_prints_the_started_cycle_or_says_it_did_not_come(tmp_path):
    """``cmd --wait``: the reply, then the cycle's result; a result that does not come
    within SECONDS is the documented exit, with what was waited for (a real-time cycle
    lasts far longer than the 0.5 s given here)."""
    from support.harness import Daemon, sim_config

    doc = _documented_exits()
    (late,) = {code for (cmd, case), code in doc.items() if cmd == "cmd" and "--wait [SECONDS]" in case}
    cell = sim_config(tmp_path, clock="realtime")
    daemon = Daemon(cell)
    try:
        daemon.wait_welcome()
        run_ = subprocess.run([sys.executable, "-m", "fluidsense", "cmd", '{"cmd": "cycle"}', "--config", str(cell),
                               "--wait", "0.5"], cwd=REPO, capture_output=True, text=True, timeout=60)
        assert run_.returncode == late, run_.stdout + run_.stderr
        started = json.loads(run_.stdout)
        assert started["ok"] and "no cycle of cycle" in run_.stderr, run_.stderr
        assert daemon.request({"cmd": "status"})["cycle_id"] == started["cycle_id"]
    finally:
        assert daemon.close() == 0


def test_cmd_grip_wait_prints_the_grasp_and_the_gripper_holds_until_release(tmp_path):
    """A held grip's cycle ends only at its release, so ``cmd grip --wait`` answers with the
    grasp (object, features), and the daemon still holds until ``cmd release``."""
    from support.harness import Daemon, sim_config

    cell = sim_config(tmp_path)
    daemon = Daemon(cell)
    try:
        daemon.wait_welcome()
        run_ = subprocess.run([sys.executable, "-m", "fluidsense", "cmd", "grip", "--config", str(cell),
                               "--wait", "120"], cwd=REPO, capture_output=True, text=True, timeout=180)
        assert run_.returncode == 0, run_.stdout + run_.stderr
        decoder = json.JSONDecoder()
        reply, end = decoder.raw_decode(run_.stdout)
        grasp, _ = decoder.raw_decode(run_.stdout[end:].lstrip())
        assert reply["ok"] and grasp["topic"] == "grasp" and grasp["cycle_id"] == reply["cycle_id"]
        assert "object" in grasp and "p_eq_kpa" in grasp["features"]
        assert daemon.request({"cmd": "status"})["holding"] is True
        assert daemon.request({"cmd": "release"})["ok"]
    finally:
        assert daemon.close() == 0
