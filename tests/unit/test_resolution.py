"""Resolution: numerical model against eq. 2, 10 and 11; the design search."""

from __future__ import annotations

import json

import numpy as np
import pytest
from fluidsense.common.hardware import GripperActuator, LinearActuator
from fluidsense.common.scenes import CylinderScene, WallScene
from fluidsense.common.units import KPA, LITRE, ML, P_ATM
from fluidsense.simulator.actuators import volume_law
from fluidsense.simulator.equilibrium import eq2_resolution, equilibrium
from fluidsense.simulator.gas import Network, Pipe, VolumeLaw
from fluidsense.simulator.plant import Plant
from fluidsense.simulator.resolution import evaluate, linear_sweep, resolution_at, search
from support.cli import run_cli
from support.harness import REPO

SWEEPS = {
    "l0_mm": np.linspace(20, 1500, 12),
    "area_mm2": np.linspace(100, 3000, 12),
    "stiffness_n_per_m": np.geomspace(50, 5000, 12),
    "p0_kpa": np.linspace(10, 90, 9),
    "tank_l": np.geomspace(0.02, 1.0, 9),
}


@pytest.mark.parametrize("param", list(SWEEPS))
def test_numeric_and_analytic_resolution_agree_wherever_contact_happens(param):
    """Fig. S modelV4 f-i: numerical model = eq. 11 within 2 % while the actuator reaches the
    wall, zero resolution once it cannot."""
    rows = linear_sweep(param, SWEEPS[param], wall_mm=20.0)
    for row in rows:
        if row["contact"]:
            assert row["numeric_kpa_per_mm"] == pytest.approx(row["analytic_kpa_per_mm"], rel=0.02), row
        elif not row["edge"]:  # (at the edge of reach the difference straddles the kink)
            assert abs(row["numeric_kpa_per_mm"]) < 1e-9 and abs(row["analytic_kpa_per_mm"]) > 1e-3
    if param in ("l0_mm", "stiffness_n_per_m"):
        # longer or stiffer: eventually the wall is out of reach (the paper's vanishing resolution)
        assert rows[0]["contact"] and not rows[-1]["contact"]


def test_resolution_rises_with_p0_and_k_does_not_matter_while_in_contact():
    """Paper: |dp1/dL| grows with p0; k leaves eq. 11 unchanged as long as contact happens."""
    p0 = [r["numeric_kpa_per_mm"] for r in linear_sweep("p0_kpa", [30, 50, 70])]
    assert abs(p0[0]) < abs(p0[1]) < abs(p0[2])
    k = [r for r in linear_sweep("stiffness_n_per_m", [100, 200, 300]) if r["contact"]]
    assert len(k) == 3 and np.ptp([r["numeric_kpa_per_mm"] for r in k]) < 1e-3


def test_gripper_resolution_satisfies_eq2():
    """eq. 2 with the simulated dv1/dD reproduces the numerical dp1/dD."""
    act, vt, p0 = GripperActuator(), 0.3 * LITRE, 63 * KPA
    pt = resolution_at(act, lambda d: CylinderScene(diameter_mm=d), 70.0, 1.0, p0, vt, P_ATM)
    v = [float(volume_law(act, CylinderScene(diameter_mm=d), P_ATM).volume_at(
        equilibrium(p0, vt, volume_law(act, CylinderScene(diameter_mm=d), P_ATM), P_ATM))) for d in (69.0, 71.0)]
    dv_dd = (v[1] - v[0]) / 2.0
    v1 = float(volume_law(act, CylinderScene(diameter_mm=70), P_ATM).volume_at(pt.p_eq))
    assert pt.dp_dxi == pytest.approx(eq2_resolution(p0, vt, act.v0, v1, dv_dd, P_ATM), rel=0.01)
    assert dv_dd / ML == pytest.approx(-0.13, abs=0.02)  # Table S1


def test_design_search_picks_the_best_feasible_and_the_plant_agrees():
    act = LinearActuator()
    targets = [0.0, 10.0, 20.0, 30.0]
    best, grid = search(act, lambda x: WallScene(distance_mm=x), targets, [0.02, 0.05, 0.1, 0.3],
                        [20, 40, 60, 80], P_ATM, (-5, 80), (-103.4, 103.4))
    assert best is not None and best.feasible
    assert best.min_resolution == max(d.min_resolution for d in grid if d.feasible)
    assert any(not d.feasible and "no contact" in d.reason for d in grid)  # small tank, low P0
    # the dynamic plant (eq. 3-9) settles where the static model says, at the recommendation
    law = volume_law(act, WallScene(distance_mm=30.0), P_ATM)
    net = Network(["tank", "actuator"], [VolumeLaw.constant(best.tank_l * LITRE), law], [Pipe(0, 1, 1e8, "v", True)])
    plant = Plant(net, {"v": True}, P_ATM, 0.05, p_initial_abs={"tank": P_ATM + best.p0_kpa * KPA})
    state, _ = plant.sample(np.array([60.0]))
    p_dyn = plant.pressures_abs(state)[1, 0] - P_ATM
    assert p_dyn / KPA == pytest.approx(best.p_eq_range_kpa[0], rel=1e-3)
    # the search keeps one volume law per target value across the grid: every grid point is
    # what evaluating it alone, each law built afresh, gives
    alone = [evaluate(act, lambda x: WallScene(distance_mm=x), targets, d.tank_l, d.p0_kpa, P_ATM, (-5, 80),
                      (-103.4, 103.4)) for d in grid]
    assert [d.to_dict() for d in grid] == [d.to_dict() for d in alone]


def test_design_command(tmp_path, capsys):
    out = run_cli(capsys, "design", "--profile", "pneunet-gripper", "--json", cwd=REPO)
    assert out.returncode == 0, out.stderr
    data = json.loads(out.stdout)
    assert data["recommended"]["feasible"] and data["improvement"] >= 1.0
    assert data["current"]["min_resolution"] == pytest.approx(0.041, rel=0.1)
    assert data["resolution_unit"] == "kPa/mm"


def test_design_for_a_requirement_takes_the_lowest_p0_that_meets_it_and_says_why_not(capsys):
    """--resolution-mm/--decide-by-s: a loose requirement is met below the P0 limit (not
    pushed to it); one the noise cannot reach, or a decision before the transient has
    settled, gets no design and a reason."""
    import json as _json

    def design(*extra):
        out = run_cli(capsys, "design", "--profile", "pneunet-gripper", "--tanks", "0.1,0.3,1.0", "--json", *extra,
                      cwd=REPO)
        return out.returncode, _json.loads(out.stdout)

    rc, loose = design("--resolution-mm", "4", "--decide-by-s", "10")
    best = loose["recommended"]
    assert rc == 0 and best["meets"] and best["half_width"] <= 4 and best["settle_s"] < 10
    assert best["p0_kpa"] <= 90.0 - loose["p0_margin_kpa"] and best["p0_kpa"] < 60.0  # lowest that does it
    rc, tight = design("--resolution-mm", "0.05", "--decide-by-s", "10")
    assert rc == 1 and tight["recommended"] is None and "noise" in tight["why_none"]
    rc, early = design("--resolution-mm", "4", "--decide-by-s", "0.05")
    assert rc == 1 and "settle" in early["why_none"]
    bad = run_cli(capsys, "design", "--profile", "pneunet-gripper", "--resolution-mm", "1", cwd=REPO)
    assert bad.returncode == 2 and "together" in bad.stderr
