"""The committed reproduction report is what `python -m lab report` produces.

(Its tests with real peers: tests/system/test_report.py.)
"""

from __future__ import annotations

import json

import pytest
from support.harness import REPO
from lab.report.common import Section, ledger_counts, ledger_problems

COMMITTED = REPO / "docs" / "reproduction"


@pytest.fixture(scope="module")
def committed():
    return json.loads((COMMITTED / "results.json").read_text())


def test_committed_report_covers_every_section_and_the_key_claims(committed):
    assert set(committed["sections"]) == {"distance_tank", "distance_pressure_flow", "distance_flow_control",
                                          "gripper", "shape", "stiffness", "profile", "suction", "retrofit",
                                          "resolution", "timing", "tasks"}
    rows = {r["quantity"]: r for r in committed["paper_vs_ours"]}
    tank = committed["sections"]["distance_tank"]
    assert -2.5 <= tank["err95_lo_mm"] and tank["err95_hi_mm"] <= 2.5  # the criterion
    check = rows["numerical vs analytic resolution where contact happens"]
    assert (check["kind"], check["holds"]) == ("self-check", True)  # our code against eq. 11, not a paper row
    assert ledger_problems(committed["paper_vs_ours"]) == []
    assert committed["ledger"] == ledger_counts(committed["paper_vs_ours"])
    n = committed["ledger"]
    assert n["predicted"] == n["numeric_agree"] + n["numeric_disagree"] + n["qualitative"]
    # the paper's closed-loop tasks are in the ledger, from the task files
    assert {r["quantity"] for r in committed["paper_vs_ours"] if r["source"].startswith("Results, ripeness")} == {
        f"ripeness success, {d0}, {who}" for d0 in ("t_c at the first rise of dP", "t_c at dP = 2 kPa",
                                                    "dP_max instead of t_c") for who in ("rigid dummy", "tomatoes")}
    assert any(r["quantity"].startswith("tomato picking") for r in committed["paper_vs_ours"])
    for png in ("distance_tank.png", "gripper_size.png", "shape_rectangles.png", "profile_scan.png", "suction.png",
                "retrofit.png", "resolution_sweeps.png"):
        assert (COMMITTED / png).stat().st_size > 10_000


def _rows(*specs):
    sec = Section("x", "x")
    for args, kw in specs:
        sec.row(*args, **kw)
    return sec.rows


def test_a_figure_a_parameter_was_set_from_is_never_a_prediction():
    """The audit's case: Table S1's |dp1/dD| = 0.04 kPa/mm follows by eq. 2 from the same
    gripper's |dv1/dD| = 0.13 ml/mm that the wrap ratio is set from; as a prediction it flatters."""
    fitted = (("|dv1/dD|", "0.13 ml/mm", "0.129 ml/mm", True, "", "Table S1"),
              dict(kind="fitted", parameter="wrap_ratio", set_from=("0.13 ml/mm",), figures=("0.13 ml/mm",),
                   tolerance="+-0.005 ml/mm"))
    consistency = (("|dp1/dD|", "0.04 kPa/mm", "0.0426 kPa/mm", True, "", "Table S1"),
                   dict(kind="fitted", parameter="wrap_ratio, v0", set_from=("0.13 ml/mm",),
                        figures=("0.04 kPa/mm",), tolerance="+-0.005 kPa/mm"))
    as_prediction = (("gripper slope", "about 0.04 kPa/mm", "0.0418 kPa/mm", True, "", "Fig. 1f"),
                     dict(kind="predicted", figures=("0.04 kPa/mm",), tolerance="+-0.005 kPa/mm"))
    assert ledger_problems(_rows(fitted, consistency)) == []
    problems = ledger_problems(_rows(fitted, consistency, as_prediction))
    assert len(problems) == 1 and "gripper slope" in problems[0] and "0.04 kPa/mm" in problems[0]
    # the same number of another unit is another figure
    other = (("q", "0.04 mm", "0.04 mm", True, "", "Fig. 9"), dict(kind="predicted", figures=("0.04 mm",),
                                                                     tolerance="t"))
    assert ledger_problems(_rows(fitted, consistency, other)) == []


def test_a_claim_without_a_published_number_is_qualitative_whatever_it_shows():
    rows = _rows((("stiffness ranking", "softer: larger indentation", "ranked correctly", True, "", "Fig. 2f"),
                  dict(kind="predicted")),
                 (("fast sorting", "38.21 +- 0.11 kPa (sd)", "39.70 kPa", False, "fills faster", "Fig. S"),
                  dict(kind="predicted", figures=("38.21 kPa",), tolerance="2 sd of the paper's readings")))
    assert [(r["verdict"], r["holds"]) for r in rows] == [("qualitative", True), ("mismatch", None)]
    assert ledger_counts(rows) == {"predicted": 2, "numeric_agree": 0, "numeric_disagree": 1, "qualitative": 1,
                                   "fitted": 0, "self_checks": 0}
    with pytest.raises(ValueError, match="tolerance"):
        _rows((("q", "1.0 kPa", "1.0 kPa", True, "", "Fig. 1"), dict(kind="predicted", figures=("1.0 kPa",))))
    with pytest.raises(ValueError, match="not in the row's published text"):
        _rows((("q", "2.0 kPa", "1.0 kPa", True, "", "Fig. 1"), dict(kind="predicted", figures=("1.0 kPa",),
                                                                       tolerance="t")))
    with pytest.raises(ValueError, match="parameter and the figure"):
        _rows((("q", "2.0 kPa", "1.0 kPa", True, "", "Fig. 1"), dict(kind="fitted", parameter="k")))
