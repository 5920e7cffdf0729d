"""Design and chart for your own actuator (issue 36 item 3): ``fluidsense design`` takes a
characterised profile as it takes a shipped one, and ``fluidsense chart`` draws speed
against accuracy for any profile and scene from virtual-time cycles on the simulated cell
(tasks/speed_accuracy.py, the core the lab's paper study calls too)."""

from __future__ import annotations

import datetime
import json
import math
import re
import subprocess
import sys
import zipfile

import pytest
import yaml
from fluidsense.cli import main as cli_main
from fluidsense.common.scenes import CylinderScene
from fluidsense.controller.config import load_profile
from fluidsense.controller.config.loading import read_yaml
from fluidsense.controller.config.profile import FittedNumber
from fluidsense.tasks import characterise as ch
from fluidsense.tasks import speed_accuracy as sa
from support.harness import REPO

START = "pneunet-gripper-quick"  # 6 s cycles; its first window ends at 2.5 s
RIG = "driver modbus at 10.0.0.7"
# small runs: the figures' consistency, not their precision
TRIALS, CAL_CYCLES = "30", "3"
CONTACT_METHODS = ("early", "t_c_slope", "t_c_threshold", "dp_max")


def characterised_file(tmp_path, name: str = "mine", v0: float = 1.3, c: float = 1.3, resistor: float = 2.0):
    """A profile as ``fluidsense characterise`` writes one (its writer and header: the
    starting profile with the fitted fields set and a provenance block), from no cycles:
    the quick PneuNet with its free volume, compliance and the path's resistance scaled by
    these factors (each given a 95 % interval of +-10 %)."""
    start_path = REPO / "config" / "profiles" / f"{START}.yaml"
    start = load_profile(start_path)
    values = {"actuator.v0_ml": (start.actuator.v0_ml * v0, "ml"),
              "actuator.compliance_ml_per_kpa": (start.actuator.compliance_ml_per_kpa * c, "ml/kPa"),
              "circuit.resistor_pa_s_per_m3": (start.circuit.resistor_pa_s_per_m3 * resistor, "Pa s/m^3")}
    fitted = [FittedNumber(field=k, value=v, lo95=0.9 * v, hi95=1.1 * v, unit=u, how="written by the test")
              for k, (v, u) in values.items()]
    result = ch.Characterisation(fitted=fitted, measured=[], kept={"circuit.tank_l": "as the config states it"},
                                 notes=[], residual_kpa=0.02, pure_error_kpa=0.04)
    data = ch.characterised_profile(read_yaml(start_path), start, result, name=f"{START}-characterised", rig=RIG,
                                    config="/cells/mine.yaml", from_profile=f"{START} ({start_path})",
                                    levels=[12.6, 25.2, 37.8, 50.4, 63.0], cycles=4, cycle_ids=list(range(1, 21)),
                                    date=datetime.datetime(2026, 11, 1, tzinfo=datetime.UTC))
    path = tmp_path / f"{name}.yaml"
    path.write_text(ch.profile_comments(result, f"{RIG}, 2026-11-01") + yaml.safe_dump(data, sort_keys=False))
    return path


def _cli_json(capsys, *args) -> dict:
    assert cli_main(list(args)) == 0
    return json.loads(capsys.readouterr().out)


# ------------------------------------------------------------------ design
def test_design_takes_a_characterised_profile_by_file_and_by_name(tmp_path, monkeypatch, capsys):
    """The file's numbers, not the shipped ones, are designed for; by name (mine for
    ./mine.yaml) as by file; the JSON says where they came from. A name that is both
    yours and a shipped one is refused rather than guessed."""
    path = characterised_file(tmp_path)
    prof = load_profile(path)
    assert prof.provenance is not None and prof.provenance.rig == RIG
    monkeypatch.chdir(tmp_path)
    by_file = _cli_json(capsys, "design", "--profile", str(path), "--json")
    by_name = _cli_json(capsys, "design", "--profile", "mine", "--json")
    shipped = _cli_json(capsys, "design", "--profile", START, "--json")
    assert by_file == by_name
    assert by_file["recommended"] is not None and by_file["profile"] == f"{START}-characterised"
    assert by_file["provenance"]["rig"] == RIG
    assert by_file["provenance"]["fitted"]["actuator.v0_ml"]["value"] == pytest.approx(prof.actuator.v0_ml)
    assert shipped["provenance"] is None
    # a larger, more compliant actuator resolves the range differently at the same tank and P0
    assert by_file["current"]["min_resolution"] != pytest.approx(shipped["current"]["min_resolution"], rel=0.01)
    needs = _cli_json(capsys, "design", "--profile", "mine", "--resolution-mm", "5", "--decide-by-s", "3", "--json")
    assert needs["recommended"] is not None and needs["provenance"]["rig"] == RIG
    (tmp_path / f"{START}.yaml").write_text(path.read_text())
    assert cli_main(["design", "--profile", START]) == 2
    assert "both" in capsys.readouterr().err


# ------------------------------------------------------------------ the chart
def _chart(tmp_path, profile: str, *extra: str) -> tuple[dict, subprocess.CompletedProcess]:
    out = tmp_path / "chart"
    run = subprocess.run([sys.executable, "-m", "fluidsense", "chart", "--profile", profile, "--trials", TRIALS,
                          "--cal-cycles", CAL_CYCLES, "--out", str(out), "--json", *extra], capture_output=True,
                         text=True, cwd=tmp_path, timeout=600)
    assert run.returncode == 0, run.stderr
    res = json.loads(run.stdout)
    assert json.loads((out / sa_json()).read_text()) == res
    png = (out / "speed_accuracy.png").read_bytes()
    assert png.startswith(b"\x89PNG\r\n\x1a\n") and len(png) > 20_000
    return res, run


def sa_json() -> str:
    from fluidsense.cli.subcommands.chart import JSON

    return JSON


def check_figures(res: dict) -> None:
    """What any chart's figures must satisfy, whatever the actuator."""
    trials, fl, rows = res["trials"], res["floor"], res["rows"]
    assert 0 < fl["contact_s"] < fl["settled_s"] and fl["settled_kpa"] > 0
    times = res["decision_times_s"]
    assert times == sorted(times) and times[-1] == res["reference"]["decision_time_s"]
    assert len(rows) == 5 * len(times)
    for r in rows:
        f = r["decided_fraction"]
        assert 0.0 <= f <= 1.0, r
        assert abs(f * trials - round(f * trials)) < 0.01, r  # a count of held-out cycles (to 4 digits)
        assert (r["err95"] is None) == (f == 0.0), r  # an error exactly when something was decided
        if r["err95"] is not None:
            assert r["err95"] >= 0 and math.isfinite(r["bias"]), r
    by = {(r["method"], r["decision_time_s"]): r for r in rows}
    for m in {r["method"] for r in rows}:
        # once the pressure has settled a reading no longer depends on when it is taken: what
        # decides keeps deciding (one held-out cycle's inversion may come and go)
        after = [by[m, t]["decided_fraction"] for t in times if t >= fl["settled_s"]]
        assert after and all(b >= a - 1.0 / trials - 1e-9 for a, b in zip(after, after[1:])), (m, after)
    for m in CONTACT_METHODS:  # before the farthest target is touched, some cycles have no contact yet
        assert all(by[m, t]["decided_fraction"] < 1.0 for t in times if t < fl["contact_s"]), m
    ref = res["reference"]["err95"]
    span = res["range"][1] - res["range"][0]
    assert 0 < ref < span / 5  # the profile's own reading resolves the range
    early = [by["window", t]["err95"] for t in times if t < 0.5 * fl["contact_s"]]
    assert early and min(early) > 3 * ref  # before contact the window sees the free actuator
    for e in res["earliest"]:  # nothing decides at the reference's accuracy before the farthest contact
        assert e["decision_time_s"] is None or e["decision_time_s"] >= fl["contact_s"], e
    assert any(e["decision_time_s"] is not None for e in res["earliest"])


@pytest.fixture(scope="module")
def shipped_chart(tmp_path_factory):
    return _chart(tmp_path_factory.mktemp("shipped"), START)


def test_the_chart_of_a_shipped_profile_is_consistent_and_says_its_progress(shipped_chart):
    res, run = shipped_chart
    check_figures(res)
    assert res["profile"] == START and res["provenance"] is None and res["target"] == "diameter_mm"
    assert res["range"] == [40, 100] and res["calibration_targets"] == [40, 55, 70, 85, 100]
    assert res["reference"]["decision_time_s"] == 2.5  # the end of the profile's own first window
    assert res["command"].startswith(f"fluidsense chart --profile {START} ")
    # stderr is not a terminal here: progress lines, the last at 100 %
    lines = [x for x in run.stderr.splitlines() if x.startswith(f"charting {START}: ")]
    assert len(lines) >= 10 and lines[-1].endswith("(100 %)"), run.stderr
    stages = {re.fullmatch(rf"charting {START}: (.+) \d+/\d+ \(\d+ %\)", x).group(1) for x in lines}
    assert stages == {"running cycles", "reading features", "scoring"}


def test_the_chart_of_a_characterised_profile_uses_its_numbers(tmp_path, shipped_chart):
    """The characterised file's own circuit: twice the path's resistance fills the actuator
    more slowly, so its farthest target is touched later and it settles later than the
    shipped profile's."""
    characterised_file(tmp_path)
    res, _ = _chart(tmp_path, "mine")
    check_figures(res)
    shipped, _ = shipped_chart
    assert res["provenance"]["rig"] == RIG and RIG in res["source"]
    assert "actuator.v0_ml" in res["provenance"]["fitted"]
    assert res["floor"]["contact_s"] > 1.2 * shipped["floor"]["contact_s"]
    assert res["floor"]["settled_s"] > 1.2 * shipped["floor"]["settled_s"]


def test_a_paper_scene_charted_by_the_command_gives_the_labs_figures(tmp_path):
    """The paper's gripper on cylinders (fast circuit, 0.05 s lag) as a profile file:
    ``fluidsense chart`` on it gives the lab's rows at every decision time they share, the
    same cycles scored by the same code (the lab's grid ends at 5 s, the profile's window
    at 5.5 s)."""
    from lab.bench import speed_accuracy as SA

    scene, circuit = SA.CHECK_PAIR
    prof = SA._profile(SA.SCENES[scene][0], SA.CIRCUITS[circuit], SA._response_s(None))
    path = tmp_path / "paper-gripper.yaml"
    path.write_text(yaml.safe_dump(prof.model_dump(mode="json"), sort_keys=False))
    out = tmp_path / "chart"
    assert cli_main(["chart", "--profile", str(path), "--scene", "cylinder", "--range", "40,100", "--trials", "12",
                     "--cal-cycles", "3", "--early-half-width", "2", "--out", str(out)]) == 0
    res = json.loads((out / sa_json()).read_text())
    lab = SA.run_bench(trials=12, cal_cycles=3, only=SA.CHECK_PAIR)
    assert res["floor"]["contact_s"] == lab["floors"][f"{scene} {circuit}"]["contact_s"]
    mine = {(r["method"], r["decision_time_s"]): r for r in res["rows"]}
    shared = [r for r in SA._round(lab["rows"]) if (r["method"], r["decision_time_s"]) in mine]
    assert len(shared) >= 5 * len(SA.DECISION_TIMES)
    for r in shared:
        m = mine[r["method"], r["decision_time_s"]]
        assert (m["err95"], m["bias"], m["decided_fraction"]) == (r["err95_mm"], r["bias_mm"],
                                                                  r["decided_fraction"]), (m, r)


def test_the_chart_refuses_what_it_cannot_draw(tmp_path, capsys):
    out = str(tmp_path / "x")
    assert cli_main(["chart", "--profile", "pneunet-bending-pressure-flow", "--out", out]) == 2
    assert "tank" in capsys.readouterr().err
    # the quick PneuNet closes on 40-100 mm; 2 mm is never reached at its P0
    assert cli_main(["chart", "--profile", START, "--range", "2,100", "--out", out]) == 2
    assert "does not reach diameter_mm = 2" in capsys.readouterr().err
    assert cli_main(["chart", "--profile", START, "--targets", "40,40,100", "--out", out]) == 2
    assert "at least 3 distinct" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()  # nothing written


def test_the_wheel_has_the_chart_and_it_runs_without_the_checkout(tmp_path):
    """The command and its core are product code: in the wheel, and run from it outside the
    checkout (no lab/, no tests/ on the path)."""
    dist = tmp_path / "dist"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "--wheel-dir", str(dist), str(REPO)],
                   check=True, capture_output=True, timeout=600)
    (wheel,) = dist.glob("fluidsense-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {"fluidsense/tasks/speed_accuracy.py", "fluidsense/cli/subcommands/chart.py",
            "fluidsense/cli/speed_chart.py", "fluidsense/drivers/sim/floor.py"} <= names
    site, cwd = tmp_path / "site", tmp_path / "elsewhere"
    cwd.mkdir()
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--quiet", "--target", str(site), str(wheel)],
                   check=True, capture_output=True, timeout=600)
    run = subprocess.run([sys.executable, "-m", "fluidsense", "chart", "--profile", START, "--trials", "4",
                          "--cal-cycles", "2", "--out", "here", "--json"], cwd=cwd, capture_output=True, text=True,
                         env={"PYTHONPATH": str(site), "PATH": "/usr/bin"}, timeout=600)
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout)["profile_file"].startswith(str(site))
    assert (cwd / "here" / "speed_accuracy.png").is_file()


def test_the_grid_reaches_a_profiles_own_reading(tmp_path):
    """The coarse grid is the 1-2-3-5 series up to the profile's first window's end, which
    it ends on; the actuation is cut after the last window, never before it."""
    assert sa.coarse_times(2.5) == (0.1, 0.2, 0.3, 0.5, 1.0, 2.0, 2.5)
    assert sa.coarse_times(60.0)[-3:] == (30.0, 50.0, 60.0)
    prof = load_profile(REPO / "config" / "profiles" / "tomato-gripper.yaml")  # three windows, the last at 26 s
    scene = sa.ChartScene(base=CylinderScene(diameter_mm=50.0), target="diameter_mm", unit="mm",
                          calibration=(50.0, 60.0, 70.0), range=(50.0, 70.0))
    prepared, plan = sa.for_profile(prof, scene)
    assert plan.last_s == prof.sequence.windows[0].end_s == 26.0
    assert prepared.sequence.actuate_s == 26.5 and prepared.calibration is None
    assert plan.early_half_width == pytest.approx(20.0 / 30)
