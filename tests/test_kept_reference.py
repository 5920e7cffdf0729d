"""The free-air reference survives a restart while it still belongs to the cell
(controller/cycles/kept.py): a daemon killed with SIGKILL and started again grips with the
reference it kept; one whose profile changed refuses it, saying why, and its grip says how
to take a new one. Real daemon processes on the simulated cell, in virtual time."""

from __future__ import annotations

import json

from fluidsense.controller.config import load_cell_config
from fluidsense.controller.cycles.kept import KIND, ReferenceKeeper, identity
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


def test_a_changed_p0_has_no_reference_at_its_p0_and_other_parts_are_named(tmp_path):
    """P0 is each reference's key: one kept at 63 kPa still serves cycles at 63 kPa, not a
    profile whose P0 became 60 kPa. Every other part of the identity refuses it by name."""
    cfg = load_cell_config(sim_config(tmp_path))
    lower = load_cell_config(sim_config(tmp_path, profile=str(profile_config(tmp_path, PROFILE,
                                                                             sequence={"p0_kpa": 60.0}))))
    assert identity(lower) == identity(cfg)  # the same cell: only the default P0 moved
    slower = load_cell_config(sim_config(tmp_path, profile=str(profile_config(tmp_path, PROFILE,
                                                                              sequence={"charge_s": 12.0}))))
    faster = load_cell_config(sim_config(tmp_path, driver={"rate_hz": 500}))
    for other, part in ((slower, "sequence"), (faster, "driver")):
        assert [p for p in identity(cfg) if identity(cfg)[p] != identity(other)[p]] == [part]
    # a kept file with a reference at 63 kPa, read by the 60 kPa profile's daemon: kept, at 63 kPa only
    path = tmp_path / "refs.json"
    keeper = ReferenceKeeper(path, identity(cfg))
    from fluidsense.controller.cycles.analysis import Reference
    import numpy as np

    keeper.add(P0_KPA * 1e3, P0_KPA, Reference(np.array([0.0, 0.001]), np.array([0.0, 10.0]), 3))
    keeper.write(keeper.snapshot())
    back = ReferenceKeeper(path, identity(lower))
    assert list(back.load()) == [P0_KPA] and back.refused == []
    assert ReferenceKeeper(path, identity(slower)).load() == {}


def test_a_garbled_or_foreign_file_is_refused_with_the_reason_and_nothing_else_happens(tmp_path):
    cfg = load_cell_config(sim_config(tmp_path))
    path = tmp_path / "refs.json"
    for text, reason in (("{not json", "Expecting property name"), ('{"kind": "something else"}', "not a file of"),
                         (json.dumps({"kind": KIND, "version": 1, "references": [{"p0_kpa": "63"}]}), "identity")):
        path.write_text(text)
        keeper = ReferenceKeeper(path, identity(cfg))
        assert keeper.load() == {}
        assert reason in (keeper.error or "") + json.dumps(keeper.refused), (text, keeper.error, keeper.refused)
    path.unlink()
    path.mkdir()  # not a regular file
    keeper = ReferenceKeeper(path, identity(cfg))
    assert keeper.load() == {} and "not a regular file" in keeper.error
