"""The committed reproduction report is what `fluidsense report` produces."""

from __future__ import annotations

import json

import pytest

from fluidsense.report import generate

from .conftest import REPO

COMMITTED = REPO / "docs" / "reproduction"


def _close(a, b, path=""):
    """Equal up to the last of four significant digits (a newer scipy may move it)."""
    if isinstance(a, dict):
        assert set(a) == set(b), path
        for k in a:
            _close(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            _close(x, y, f"{path}[{i}]")
    elif isinstance(a, float) and isinstance(b, (int, float)):
        assert a == pytest.approx(b, rel=2e-3, abs=1e-6), path
    else:
        assert a == b, path


@pytest.fixture(scope="module")
def regenerated(tmp_path_factory):
    out = tmp_path_factory.mktemp("reproduction")
    return generate(out, jobs=2), out


def test_report_reproduces_the_committed_numbers(regenerated):
    res, out = regenerated
    committed = json.loads((COMMITTED / "results.json").read_text())
    assert committed["seed"] == res["seed"]
    _close(res["sections"], committed["sections"], "sections")
    assert [r["verdict"] for r in res["paper_vs_ours"]] == [r["verdict"] for r in committed["paper_vs_ours"]]
    assert (out / "README.md").read_text().count("![") == (COMMITTED / "README.md").read_text().count("![")


def test_report_covers_every_section_and_the_key_claims(regenerated):
    res, out = regenerated
    assert set(res["sections"]) == {"distance_tank", "distance_pressure_flow", "distance_flow_control", "gripper",
                                    "shape", "stiffness", "profile", "suction", "retrofit", "resolution", "timing"}
    rows = {r["quantity"]: r for r in res["paper_vs_ours"]}
    tank = res["sections"]["distance_tank"]
    assert -2.5 <= tank["err95_lo_mm"] and tank["err95_hi_mm"] <= 2.5  # the criterion
    assert rows["numerical vs analytic resolution where contact happens"]["verdict"] == "match"
    for png in ("distance_tank.png", "gripper_size.png", "shape_rectangles.png", "profile_scan.png", "suction.png",
                "retrofit.png", "resolution_sweeps.png"):
        assert (out / png).stat().st_size > 10_000
