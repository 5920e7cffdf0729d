"""The committed reproduction report is what `python -m lab report` produces.

(Its in-process tests: tests/unit/test_report.py.)
"""

from __future__ import annotations

import json

import pytest
from support.harness import REPO

from lab.report import generate
from lab.report.common import ledger_problems

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


# The suite regenerates three quick sections (about 20 s) and compares them with the
# committed report; `make report` regenerates all eleven (about nine minutes), and
# `git diff docs/reproduction` then shows any change. (The shape section, another 20 s,
# is left to `make report`; tests/system/test_scenes.py checks the rectangles' two contacts.)
QUICK = ["stiffness", "resolution", "timing"]


@pytest.fixture(scope="module")
def regenerated(tmp_path_factory):
    out = tmp_path_factory.mktemp("reproduction")
    return generate(out, jobs=2, only=QUICK), out


@pytest.fixture(scope="module")
def committed():
    return json.loads((COMMITTED / "results.json").read_text())


def test_report_reproduces_the_committed_numbers(regenerated, committed):
    res, _ = regenerated
    assert committed["seed"] == res["seed"]
    assert len(res["sections"]) == len(QUICK)
    _close(res["sections"], {k: committed["sections"][k] for k in res["sections"]}, "sections")
    by_quantity = {r["quantity"]: r for r in committed["paper_vs_ours"]}
    assert res["paper_vs_ours"], "the quick sections add rows to the paper-versus-ours table"
    for row in res["paper_vs_ours"]:
        old = by_quantity[row["quantity"]]
        assert (row["ours"], row["verdict"], row["kind"]) == (old["ours"], old["verdict"], old["kind"]), row["quantity"]
    assert ledger_problems(res["paper_vs_ours"]) == []


def test_regenerated_sections_draw_their_figures(regenerated):
    _, out = regenerated
    for png in ("resolution_sweeps.png", "stiffness.png"):
        assert (out / png).stat().st_size > 10_000
