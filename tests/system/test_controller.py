"""The controller on the simulated cell, in virtual time.

(Its in-process tests: tests/unit/test_controller.py.)
"""

from __future__ import annotations

import json
import pytest
from support.cli import run_cli
from support.harness import REPO


def test_demo_json_rises_with_diameter_at_the_papers_slope(capsys):
    """`fluidsense demo --json` (the paper's Fig. 1f protocol): P_eq rises monotonically
    from 40 to 100 mm with a slope within 30 % of 0.04 kPa/mm; D = 20 barely touches."""
    # three cycles per object instead of six (the first dropped): `make demo` runs six
    out = run_cli(capsys, "demo", "--json", "--cycles", "3", cwd=REPO)
    assert out.returncode == 0, out.stderr
    data = json.loads(out.stdout)
    pts = {p["diameter_mm"]: p for p in data["points"]}
    assert set(pts) == {None, 20, 40, 60, 80, 100}
    assert all(p["cycles"] == 2 for p in pts.values())
    rising = [pts[d]["p_eq_kpa"] for d in (40, 60, 80, 100)]
    assert all(b > a for a, b in zip(rising, rising[1:]))
    assert data["slope_kpa_per_mm"] == pytest.approx(0.04, rel=0.3)
    assert data["r2"] > 0.99
    assert abs(pts[20]["p_eq_kpa"] - pts[None]["p_eq_kpa"]) < 0.2  # barely touching
    assert pts[None]["p_eq_kpa"] == pytest.approx(34.6, abs=0.2)
