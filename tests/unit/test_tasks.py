"""The closed-loop tasks on the simulated cell, in virtual time, scored against the truth.

(Its tests with real peers: tests/system/test_tasks.py.)
"""

from __future__ import annotations

import pytest
from fluidsense.common.errors import ConfigError
from fluidsense.controller.config import load_cell_config
from fluidsense.daemon import app
from fluidsense.tasks.config import cell_path, load_task
from fluidsense.tasks.runner import run_task
from support.configs import task_config
from support.harness import CONFIG, run

TASKS = CONFIG / "tasks"


def run_file(name: str, **kw):
    path = TASKS / name
    task = load_task(path)
    if "edit" in kw:
        task = task.model_copy(update=kw.pop("edit"))
    cfg = load_cell_config(cell_path(path, task))

    async def main():
        async with app.controller(cfg) as ctrl:
            return await run_task(ctrl.task_port, task, **kw)

    return run(main())


# Every cylinder in every input slot once (a Latin square of cyclic shifts), and the fully
# reversed order (the most moves for an insertion sort). All 24 orders: the sorting part of
# python -m lab bench stability (ten orders per perturbation) and `fluidsense task run`.
ORDERS = [tuple([40.0, 60.0, 80.0, 100.0][k:] + [40.0, 60.0, 80.0, 100.0][:k]) for k in range(4)] + \
    [(100.0, 80.0, 60.0, 40.0)]


def test_every_cylinder_in_every_input_slot_sorts_correctly():
    """The paper's sorting: modified insertion sort by P_eq, no calibration."""

    async def main():
        path = TASKS / "sorting.yaml"
        task = load_task(path)
        cfg = load_cell_config(cell_path(path, task))
        results = []
        async with app.controller(cfg) as ctrl:
            for order in ORDERS:
                results.append((order, await run_task(ctrl.task_port, task, order_mm=list(order))))
        return results

    results = run(main())
    assert len(results) == len(ORDERS)
    for order, summary in results:
        assert summary["success"], (order, summary["final_order_mm"])
        assert summary["final_order_mm"] == [100.0, 80.0, 60.0, 40.0]
        vals = summary["sorted_p_eq_kpa"]
        assert vals == sorted(vals, reverse=True)
    # the readings are the paper's kind of numbers: 34-35.5 kPa for 40-100 mm
    flat = [r["p_eq_kpa"] for _, s in results for r in s["readings"]]
    assert 33.9 < min(flat) and max(flat) < 35.7


def test_tomato_picking_reports_each_tomato_against_the_truth():
    """Picked at 62 kPa; slipped into the palm (detected, picked but missed); left on the
    stem at 62 kPa and picked at 70 kPa."""
    s = run_file("picking.yaml")
    t1, t2, t3 = s["tomatoes"]
    assert t1["outcome"] == "picked_recognised" and len(t1["attempts"]) == 1
    assert t2["outcome"] == "picked_missed" and t2["truth"]["slipped"]
    assert t2["attempts"][0]["slip_detected"] and t2["decision"] == "slipped"
    assert 0.0 < t2["attempts"][0]["dp_carried_kpa"] - t2["attempts"][0]["dp_kpa"]
    assert t3["outcome"] == "picked_recognised" and [a["p0_kpa"] for a in t3["attempts"]] == [62.0, 70.0]
    assert t3["attempts"][0]["left_on_stem"] and not t3["attempts"][0]["slip_detected"]
    assert s["counts"] == {"picked_recognised": 2, "picked_missed": 1, "not_picked": 0}
    refs = s["references_kpa"]
    assert refs[62.0] < refs[70.0] < refs[78.0]


def test_a_tomato_too_heavy_for_every_step_is_not_picked():
    task = load_task(TASKS / "picking.yaml")
    heavy = [t.model_copy(update={"min_grip_kpa": 40.0, "slip_after_s": None}) for t in task.tomatoes]
    s = run_file("picking.yaml", edit={"tomatoes": heavy})
    assert [t["outcome"] for t in s["tomatoes"]] == ["not_picked"] * 3
    assert all(len(t["attempts"]) == 3 for t in s["tomatoes"])


def test_task_file_errors_name_file_and_field(tmp_path):
    bad = task_config(tmp_path, "sorting", check=False, input_slots=["in1", "nowhere"])
    with pytest.raises(ConfigError, match=rf"^{bad}: \(top level\): .*nowhere"):
        load_task(bad)
    bad = task_config(tmp_path, "sorting", check=False, motion={"speed_m_s": 7})
    with pytest.raises(ConfigError, match=rf"^{bad}: motion.speed_m_s: "):
        load_task(bad)


def test_a_task_holds_only_its_port_and_runs_on_a_fake_cell():
    """tasks/ take the controller's task port (controller/ports.py), nothing else of it: the
    size survey on a fake cell behind that port (no controller, no process), readings on a
    line of 0.0416 kPa/mm from 33.8 kPa, gives that line back, each object placed once and
    its cycles labelled."""
    from fluidsense.common.scenes import CylinderScene, EmptyScene
    from fluidsense.controller.config import load_profile
    from fluidsense.tasks.size_survey import size_survey
    from support.harness import PROFILE
    from support.taskport import CYCLE_S, FakeTaskCell

    cell = FakeTaskCell(load_profile(PROFILE), lambda scene: 33.8 + 0.0416 * getattr(scene, "diameter_mm", 0.0))
    res = run(size_survey(cell.port(), [None, 40.0, 60.0, 80.0, 100.0], cycles=3, drop_first=1))
    assert res.slope_kpa_per_mm == pytest.approx(0.0416) and res.intercept_kpa == pytest.approx(33.8)
    assert res.r2 == pytest.approx(1.0) and res.cycles_run == 15 and res.virtual_s == pytest.approx(15 * CYCLE_S)
    assert [p.p_eq_kpa for p in res.points] == pytest.approx([33.8, 35.464, 36.296, 37.128, 37.96])
    placed = [a[1] for a in cell.asked if a[0] == "place"]
    assert placed == [EmptyScene(), *(CylinderScene(diameter_mm=d) for d in (40.0, 60.0, 80.0, 100.0))]
    labels = [a[2] for a in cell.asked if a[0] == "run_cycle"]
    assert labels == ["empty"] * 3 + [f"D={d}" for d in (40.0, 60.0, 80.0, 100.0) for _ in range(3)]
