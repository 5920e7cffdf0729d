"""Every process that can move a valve stops safely on SIGTERM and SIGHUP as on Ctrl-C
(common/stopsignals.py): calibrate, sense, task run, check --actuate, the pick-and-place
example and the daemon, each a real process against the emulated UR box (``fluidsense
simcell``) while a cycle has the gripper's actuate output on. What is asserted is what the
box says: the outputs back at their safe positions within 0.5 s of the signal and the
actuator's pressure back to atmosphere; then the job's message, its exit code as
docs/cli.md gives it and, for calibrate, a journal that resumes.

The cells have no box watchdog (``watchdog: null``, as the shipped gripper config): a
process that died by the signal would leave the actuate output on, which these tests see.

(Its in-process tests: tests/unit/test_stop_signals.py.)
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import subprocess
import sys
import time

import pytest
from fluidsense.controller.config import load_cell_config
from support.docs import documented_exit
from support.harness import CONFIG, REPO, Daemon, free_simcell

SUPPLY, ACTUATE = 1 << 0, 1 << 1  # the gripper cells' valve outputs
SAFE = SUPPLY  # supply closed (normally open: energised), actuate off (the actuator vented)
VENTED_WITHIN_S = 0.5  # issue 34: from the signal to the box's outputs at their safe positions
CALIBRATION = CONFIG / "calibrations" / "pneunet-gripper-quick-p_eq.json"


def job(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "fluidsense", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=REPO, stdin=subprocess.DEVNULL,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})


def p_act_kpa(cell):
    """The actuator's pressure (kPa gauge) from the box's analog input, through the cell's wiring."""
    transfer = load_cell_config(cell).driver.wiring.sensors["p_act"].transfer
    return lambda state: transfer.to_pa(state["analog_inputs"][0]["value"]) / 1e3


def wait_actuating(box, proc, timeout_s: float = 90.0) -> None:
    """Until the box's actuate output is on (a cycle inflates the gripper), the job alive."""
    def inflating(state) -> bool:
        assert proc.poll() is None, proc.communicate()
        return bool(state["digital_outputs"] & ACTUATE)

    box.wait_for(inflating, timeout_s, "the actuate output on")


def stop_and_time(box, proc, sig: int) -> float:
    """Send ``sig``; seconds until the box reports every valve output at its safe position."""
    sent = time.monotonic()
    proc.send_signal(sig)
    box.wait_for(lambda s: s["digital_outputs"] & (SUPPLY | ACTUATE) == SAFE, 10.0, "the safe state")
    took = time.monotonic() - sent
    print(f"{signal.Signals(sig).name}: the box's outputs safe {took:.3f} s after the signal")  # with -s: the figure
    return took


def ended(proc, timeout_s: float = 60.0) -> tuple[int, str, str]:
    try:
        out, err = proc.communicate(timeout=timeout_s)
    finally:
        with contextlib.suppress(ProcessLookupError):
            proc.kill()
    return proc.returncode, out, err


def assert_vented(box, cell, took_s: float) -> None:
    assert took_s < VENTED_WITHIN_S, f"the box's outputs safe {took_s:.3f} s after the signal"
    kpa = p_act_kpa(cell)
    state = box.wait_for(lambda s: abs(kpa(s)) < 1.0, 10.0, "the actuator back to atmosphere")
    assert state["digital_outputs"] & (SUPPLY | ACTUATE) == SAFE  # and nothing inflated it again


def sigterm_after_a_journalled_cycle(box, cell, proc, journal) -> tuple[int, str]:
    """Once one cycle is finished (on disk, in ``journal``) and the next inflates, SIGTERM to
    the job; the box's outputs must be safe in time and the actuator back to atmosphere.
    The job's exit code and stderr."""
    try:
        box.wait_for(lambda s: (journal.exists() and len(journal.read_text().splitlines()) >= 2)
                     or proc.poll() is not None, 120, "the first cycle in the journal")
        wait_actuating(box, proc)
        took = stop_and_time(box, proc, signal.SIGTERM)
    finally:
        code, _, err = ended(proc)
    assert_vented(box, cell, took)
    return code, err


def test_sigterm_to_calibrate_mid_cycle_vents_and_keeps_a_resumable_journal(tmp_path):
    from fluidsense.tasks.journal import CycleJournal, journal_path

    out = tmp_path / "cal.json"
    journal = journal_path(out)
    with free_simcell(tmp_path, "gripper-modbus") as (box, cell):
        proc = job("calibrate", "--config", str(cell), "--yes", "--values", "40,60", "--cycles", "2",
                   "--drop-first", "1", "--free-cycles", "0", "--out", str(out))
        code, err = sigterm_after_a_journalled_cycle(box, cell, proc, journal)
    assert code == documented_exit("calibrate", "SIGTERM") == 143, err
    assert "calibration stopped by SIGTERM; vented: every valve at its safe position, confirmed by read-back" \
        in err, err
    kept = int(re.search(r"(\d+) of 4 cycles are kept", err).group(1))
    assert kept >= 1 and "--resume" in err and "Traceback" not in err, err
    header = json.loads(journal.read_text().splitlines()[0])  # the plan the cycles belong to
    resumed = CycleJournal.open(journal, header["plan"], resume=True)  # whole and chained: --resume accepts it
    assert len(resumed.entries) == kept and header["plan"]["values"] == [40.0, 60.0]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
def test_a_stop_signal_to_sense_mid_cycle_vents(sig, tmp_path):
    with free_simcell(tmp_path, "gripper-modbus") as (box, cell):
        proc = job("sense", "--config", str(cell), "-k", str(CALIBRATION), "--yes", "--cycles", "2")
        try:
            wait_actuating(box, proc)
            took = stop_and_time(box, proc, sig)
        finally:
            code, out, err = ended(proc)
        assert_vented(box, cell, took)
    assert code == documented_exit("sense", sig.name) == 128 + sig, err
    assert f"sensing stopped by {sig.name}; vented: every valve at its safe position, confirmed by read-back" \
        in err, err
    assert out == "" and "Traceback" not in err  # no estimate from a stopped run


def test_sigterm_to_a_task_mid_cycle_vents(tmp_path):
    with free_simcell(tmp_path, "ur") as (box, cell):
        proc = job("task", "run", "sorting", "--config", str(cell))
        try:
            wait_actuating(box, proc, timeout_s=120)
            took = stop_and_time(box, proc, signal.SIGTERM)
        finally:
            code, out, err = ended(proc)
        assert_vented(box, cell, took)
    assert code == documented_exit("task", "SIGTERM") == 143, err
    assert "task sorting stopped by SIGTERM; vented: every valve at its safe position, confirmed by read-back" \
        in err, err
    assert "Traceback" not in err


def test_sigterm_to_check_actuate_while_pulsing_vents(tmp_path):
    with free_simcell(tmp_path, "modbus") as (box, cell):
        proc = job("check", "--config", str(cell), "--seconds", "1", "--actuate", "--yes", "--pulse-s", "2")
        try:
            for line in proc.stdout:
                if line.startswith("pulsing the valves"):  # connected and vented: the pulses come next
                    break
            # a valve away from its safe position: a pulse under way (the box just powered up
            # had its normally-open supply valve open too, hence after the line above)
            box.wait_for(lambda s: s["digital_outputs"] & (SUPPLY | ACTUATE) != SAFE or proc.poll() is not None,
                         60, "a pulse")
            took = stop_and_time(box, proc, signal.SIGTERM)
        finally:
            code, out, err = ended(proc)
        assert_vented(box, cell, took)
    assert code == documented_exit("check", "SIGTERM") == 143, out + err
    assert "every valve at its safe position, confirmed by read-back" in out, out + err
    assert "check --actuate stopped by SIGTERM; vented: every valve at its safe position, confirmed by read-back" \
        in err, err
    assert "everything matches" not in out and "Traceback" not in err  # pulsing stopped there


def test_sighup_to_the_daemon_mid_grip_vents_and_exits_0(tmp_path):
    """The daemon stops on the same mechanism: SIGHUP, which used to kill it unvented, is a
    clean stop like SIGTERM."""
    with free_simcell(tmp_path, "gripper-modbus") as (box, cell):
        d = Daemon(cell)
        try:
            d.wait_welcome()
            assert d.request({"cmd": "grip"})["ok"]
            wait_actuating(box, d.proc)
            took = stop_and_time(box, d.proc, signal.SIGHUP)
        finally:
            code = d.close()
        assert_vented(box, cell, took)
    assert code == documented_exit("run", "SIGTERM, SIGINT or SIGHUP") == 0
    assert "SIGHUP received: stopping, venting first" in d.stderr_now()


def test_sigterm_to_pick_and_place_mid_cycle_has_the_daemon_vent(tmp_path):
    """The example (the arm's moves printed: no robot named) stopped while its first cycle
    inflates the gripper: it aborts the cycle, the daemon vents, the example says so from
    the daemon's read-back and exits 143; the daemon runs on."""
    with free_simcell(tmp_path, "gripper-modbus") as (box, cell):
        d = Daemon(cell)
        try:
            d.wait_welcome()
            proc = subprocess.Popen([sys.executable, str(REPO / "examples" / "pick_and_place.py"), "--cmd", d.cmd,
                                     "--pub", d.pub], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                    cwd=REPO, stdin=subprocess.DEVNULL)
            try:
                wait_actuating(box, proc)
                took = stop_and_time(box, proc, signal.SIGTERM)
            finally:
                code, out, err = ended(proc)
            assert_vented(box, cell, took)
            assert d.request({"cmd": "status"})["state"] in ("idle", "vent")  # the daemon is still there
        finally:
            assert d.close() == 0, d.stderr_now()
    assert code == 143, out + err
    assert re.search(r"pick_and_place: stopped by SIGTERM; a cycle aborted; the daemon reads the valves back at "
                     r"\{.*\}: vented", err), err
    assert "Traceback" not in err
