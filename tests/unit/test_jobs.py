"""Jobs that a fault stops say so and keep what they did: tasks, calibration (with its
journal and --resume), sensing; and a real-cell calibration never reads a prompt that
nobody can answer.

(Its tests with real peers: tests/system/test_jobs.py.)
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
from pathlib import Path

import pytest
from fluidsense.common.errors import CommandError, ConfigError, JobStopped
from fluidsense.common.scenes import CylinderScene
from fluidsense.controller.config import CellConfig, load_profile
from fluidsense.daemon import app
from fluidsense.drivers.registry import SimDriverConfig
from fluidsense.tasks.calibrate import calibrate
from fluidsense.tasks.journal import CycleJournal, journal_path
from support.cli import run_cli
from support.configs import DELETE, cell_config
from support.harness import CONFIG, REPO


def _cell(seed: int = 2) -> CellConfig:
    prof = load_profile(CONFIG / "profiles" / "sorting-gripper-quick.yaml")
    return CellConfig(driver=SimDriverConfig(clock="virtual", seed=seed), profile=prof)


PLAN = dict(target="diameter_mm", values=[40.0, 60.0, 80.0], cycles=3, drop_first=1)


def _plan(cfg) -> dict:
    return {"profile": cfg.profile.name, "scene": CylinderScene(diameter_mm=40).model_dump(), "target": PLAN["target"],
            "values": PLAN["values"], "feature": "p_eq", "fit": "linear", "cycles": PLAN["cycles"],
            "drop_first": PLAN["drop_first"]}


async def _calibrate(cfg, journal, fault_after: int | None = None):
    async with app.controller(cfg) as ctrl:
        done = {"n": 0}

        def progress(n: int) -> None:
            done["n"] += n
            if done["n"] == fault_after:  # the cell fails during the next cycle
                ctrl.backend.sim.inject("sensor_nan", ctrl.now + 1.0)

        return await calibrate(ctrl.task_port, CylinderScene(diameter_mm=40), feature="p_eq", fit="linear",
                               progress=progress, journal=journal, **PLAN)


def test_a_calibration_stopped_by_a_fault_keeps_its_cycles_and_resumes(tmp_path):
    cfg = _cell()
    path = journal_path(tmp_path / "cal.json")
    with pytest.raises(JobStopped) as stopped:
        asyncio.run(_calibrate(cfg, CycleJournal.open(path, _plan(cfg), resume=False), fault_after=3))
    exc = stopped.value
    assert exc.fault["kind"] == "sensor_nan" and "fault sensor_nan" in str(exc) and "--resume" in str(exc)
    assert exc.partial["cycles_done"] == 3 and exc.partial["cycles_total"] == 9
    kept = CycleJournal.open(path, _plan(cfg), resume=True)
    assert [(e["value"], e["k"]) for e in kept.entries] == [(40.0, 0), (40.0, 1), (40.0, 2)]
    with pytest.raises(ConfigError, match="--resume"):  # never overwritten by a new run
        CycleJournal.open(path, _plan(cfg), resume=False)
    with pytest.raises(ConfigError, match="differs in values"):  # nor mixed with another plan
        CycleJournal.open(path, {**_plan(cfg), "values": [40.0, 60.0]}, resume=True)

    resumed = asyncio.run(_calibrate(_cell(seed=3), kept)).calibration
    entries = CycleJournal.open(path, _plan(cfg), resume=True).entries
    assert len(entries) == 9 and entries[:3] == kept.entries[:3]
    used = [e for e in entries if e["k"] >= PLAN["drop_first"]]
    assert sorted(resumed.x) == sorted(e["value"] for e in used)  # the fit used the kept cycles too
    assert sorted(resumed.y) == sorted(e["y"] for e in used)
    assert resumed.slope > 0


def test_a_journal_cut_off_mid_line_resumes_from_the_last_whole_cycle(tmp_path):
    cfg = _cell()
    path = journal_path(tmp_path / "cal.json")
    journal = CycleJournal.open(path, _plan(cfg), resume=False)
    journal.add({"value": 40.0, "k": 0, "cycle_id": 1, "y": 30000.0})
    with open(path, "a") as f:
        f.write('{"value": 40.0, "k": 1, "cyc')  # the power went while a cycle was written
    again = CycleJournal.open(path, _plan(cfg), resume=True)
    assert [e["k"] for e in again.entries] == [0]
    again.add({"value": 40.0, "k": 1, "cycle_id": 2, "y": 30001.0})
    assert [e["k"] for e in CycleJournal.open(path, _plan(cfg), resume=True).entries] == [0, 1]


def test_a_journal_line_edited_moved_or_from_another_journal_is_refused_at_that_line(tmp_path):
    """A resume fits a curve through every line it accepts: a value edited by hand (one
    reading times ten gave r^2 0.021 and exit 0), two lines swapped, or a line pasted from
    another run of the same plan are refused with the line's number, before any cycle."""
    cfg = _cell()
    plan = _plan(cfg)

    def journal(name: str, ys: list[float]) -> Path:
        path = journal_path(tmp_path / name)
        j = CycleJournal.open(path, plan, resume=False)
        for k, y in enumerate(ys):
            j.add({"value": 40.0, "k": k, "cycle_id": k + 1, "y": y})
        return path

    good = journal("a.json", [30000.0, 30010.0, 30020.0])
    assert [e["y"] for e in CycleJournal.open(good, plan, resume=True).entries] == [30000.0, 30010.0, 30020.0]
    lines = good.read_text().splitlines()

    def refused(text: str) -> str:
        bad = tmp_path / "bad.json.cycles.jsonl"
        bad.write_text(text)
        with pytest.raises(ConfigError) as err:
            CycleJournal.open(bad, plan, resume=True)
        return str(err.value)

    tenfold = json.loads(lines[2])
    tenfold["y"] *= 10
    assert "bad.json.cycles.jsonl:3: not a finished cycle of this journal" in \
        refused("\n".join([*lines[:2], json.dumps(tenfold), *lines[3:]]) + "\n")
    assert ":3: " in refused("\n".join([lines[0], lines[1], lines[3], lines[2]]) + "\n")
    other = journal("b.json", [31000.0, 31010.0]).read_text().splitlines()
    assert ":4: " in refused("\n".join([*lines[:3], other[2]]) + "\n")
    # a journal from before the checksums: nothing in it can be checked
    old = [json.dumps({"kind": json.loads(lines[0])["kind"], "plan": plan}),
           *(json.dumps({k: v for k, v in json.loads(line).items() if k != "sum"}) for line in lines[1:])]
    assert "another fluidsense version" in refused("\n".join(old) + "\n")


def test_a_task_stopped_by_a_fault_reports_it_with_what_it_did():
    from fluidsense.tasks.config import load_task
    from fluidsense.tasks.runner import run_task

    task = load_task(CONFIG / "tasks" / "sorting.yaml")
    cfg = _cell()
    seen = []

    async def main():
        async with app.controller(cfg) as ctrl:
            port = ctrl.task_port

            def emit(topic, payload):
                seen.append((topic, payload))
                if topic == "task" and payload.get("event") == "measured" and payload["position"] == 0:
                    ctrl.backend.sim.inject("sensor_stuck", ctrl.now + 0.2)
                port.emit(topic, payload)

            await run_task(dataclasses.replace(port, emit=emit), task, order_mm=[60, 100, 80, 40])

    with pytest.raises(JobStopped) as stopped:
        asyncio.run(main())
    exc = stopped.value
    assert exc.fault["kind"] == "sensor_stuck" and str(exc).startswith("task sorting stopped by fault sensor_stuck")
    assert exc.partial["completed"] is False and exc.partial["steps"][0]["event"] == "measured"
    failed = [p for t, p in seen if t == "task" and p["event"] == "failed"]
    assert len(failed) == 1 and failed[0]["fault"]["kind"] == "sensor_stuck"


def test_the_operator_is_asked_in_words_and_a_scripted_run_must_name_each_target(tmp_path):
    from fluidsense.cli.subcommands.calibrate import Operator, place_text

    assert place_text(CylinderScene(diameter_mm=40)) == "place the 40 mm cylinder between the fingers"
    lines = tmp_path / "placed.txt"
    lines.write_text("40\n55\n")
    op = Operator("diameter_mm", str(lines), yes=False)

    async def main():
        await op.place(CylinderScene(diameter_mm=40))
        await op.place(CylinderScene(diameter_mm=60))

    with pytest.raises(CommandError, match="expected a line with 60.0"):
        asyncio.run(main())
    op.close()


def test_calibrating_a_real_cell_without_a_terminal_is_refused_before_anything_starts(tmp_path, capsys):
    cell = cell_config(tmp_path, "cell-modbus-sim", driver={
        "sim_control_port": DELETE,  # a real cell: nobody but the operator places targets
        "host": "127.0.0.254"})  # nothing there: the refusal must come first
    # pytest's stdin is no terminal; a connection to the box would fail the unit tier's guard
    out = run_cli(capsys, "calibrate", "--config", cell, "--out", tmp_path / "cal.json", cwd=REPO)
    assert out.returncode == 2
    assert "stdin is not a terminal" in out.stderr and "--targets-from" in out.stderr and "--yes" in out.stderr
    assert not journal_path(tmp_path / "cal.json").exists()


def test_calibrate_cli_keeps_its_journal_and_resumes(tmp_path, capsys):
    """The CLI end to end on the simulated cell: a finished run leaves its journal; a
    second run refuses to overwrite it; --resume with nothing left to run fits at once."""
    out = tmp_path / "cal.json"
    base = ["calibrate", "--profile", "sorting-gripper-quick",
            "--scene", "cylinder", "--set", "diameter_mm=40", "--target", "diameter_mm", "--values", "40,60,80", "--cycles", "2",
            "--drop-first", "1", "--out", out, "--json"]
    first = run_cli(capsys, *base, cwd=REPO)
    assert first.returncode == 0, first.stderr
    again = run_cli(capsys, *base, cwd=REPO)
    assert again.returncode == 2 and "--resume" in again.stderr
    resumed = run_cli(capsys, *base, "--resume", cwd=REPO)
    assert resumed.returncode == 0, resumed.stderr
    assert json.loads(resumed.stdout)["coeffs"] == pytest.approx(json.loads(first.stdout)["coeffs"])
