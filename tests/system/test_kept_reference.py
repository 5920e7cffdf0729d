"""The free-air reference survives a restart while it still belongs to the cell
(controller/cycles/kept.py): a daemon killed with SIGKILL and started again grips with the
reference it kept; one whose profile changed refuses it, saying why, and its grip says how
to take a new one. Real daemon processes on the simulated cell, in virtual time.

(Its in-process tests: tests/unit/test_kept_reference.py.)
"""

from __future__ import annotations

import json
from fluidsense.controller.cycles.kept import KIND
from support.configs import profile_config
from support.events import check
from support.harness import PROFILE, Daemon, sim_config

P0_KPA = 63.0  # the pneunet gripper's


def _until(d: Daemon, topic: str, match) -> dict:
    while True:
        _, msg = d.next_message(topic, timeout_s=120)
        check(topic, msg)
        if match(msg):
            return msg


def _take_reference(d: Daemon) -> dict:
    cycle = d.request({"cmd": "measure", "store_reference": True})["cycle_id"]
    _until(d, "released", lambda m: m["cycle_id"] == cycle)
    return _until(d, "log", lambda m: m["message"].startswith(f"free-air reference at {P0_KPA:g} kPa kept in"))


def _grip(d: Daemon, scene: dict) -> tuple[dict, dict]:
    assert d.request({"cmd": "scene", "scene": scene})["ok"]
    reply = d.request({"cmd": "grip"})
    assert reply["ok"], reply
    grasp = _until(d, "grasp", lambda m: m["cycle_id"] == reply["cycle_id"])
    return reply, grasp


def _killed(d: Daemon) -> None:
    d.proc.kill()  # SIGKILL: nothing of the daemon's runs after it
    assert d.proc.wait(30) == -9
    d.close()


def test_a_daemon_killed_and_restarted_grips_with_the_reference_it_kept(tmp_path):
    cell = sim_config(tmp_path)
    first = Daemon(cell)
    try:
        first.wait_welcome()
        log = _take_reference(first)
        assert str(tmp_path / "runs" / "references.json") in log["message"]
    finally:
        _killed(first)
    kept = json.loads((tmp_path / "runs" / "references.json").read_text())
    assert kept["kind"] == KIND and [r["p0_kpa"] for r in kept["references"]] == [P0_KPA]

    second = Daemon(cell)
    try:
        second.wait_welcome()
        status = second.request({"cmd": "status"})
        store = status["reference_store"]
        (ref,) = store["references"]
        assert ref["source"] == "kept" and ref["p0_kpa"] == P0_KPA and ref["age_s"] >= 0
        assert store["refused"] == [] and store["error"] is None and status["references_kpa"] == [P0_KPA]
        reply, grasp = _grip(second, {"kind": "cylinder", "diameter_mm": 60})
        assert reply["reference"] is True
        # contact decided against the kept reference: the fingers met the cylinder
        assert grasp["contact"] is True and grasp["object"] is True and grasp["t_c_s"] > 0
        assert grasp["features"]["dp_eq_kpa"] > 1.0
        assert second.request({"cmd": "release"})["ok"]
        _until(second, "released", lambda m: m["cycle_id"] == reply["cycle_id"])
    finally:
        assert second.close() == 0
    assert "taken back from" in second.stderr_now()


def test_a_changed_profile_refuses_the_kept_reference_and_the_grip_says_how_to_take_one(tmp_path):
    first = Daemon(sim_config(tmp_path))
    try:
        first.wait_welcome()
        _take_reference(first)
    finally:
        _killed(first)
    # the same cell with stiffer fingers: the free-air trace it kept is not this gripper's
    stiffer = profile_config(tmp_path, PROFILE, actuator={"compliance_ml_per_kpa": 0.9})
    second = Daemon(sim_config(tmp_path, profile=str(stiffer)))
    try:
        second.wait_welcome()
        store = second.request({"cmd": "status"})["reference_store"]
        assert store["references"] == []
        (refused,) = store["refused"]
        assert refused["p0_kpa"] == P0_KPA and refused["reason"] == \
            "the profile's actuator changed since it was measured; take a new one"
        reply, grasp = _grip(second, {"kind": "cylinder", "diameter_mm": 60})
        assert reply["reference"] is False and grasp["contact"] is None and grasp["object"] is None
        assert "measure with store_reference and nothing in the gripper" in grasp["note"]
    finally:
        assert second.close() == 0
    assert "refused: the profile's actuator changed" in second.stderr_now()
