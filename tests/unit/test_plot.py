"""``fluidsense plot``: a recorded cycle drawn from the file, the data drawn equal to the
recording's (read back independently with the recording reader)."""

from __future__ import annotations

import numpy as np
import pytest
from fluidsense.cli.plot import plot_cycles, read_cycles
from fluidsense.common.scenes import CylinderScene
from fluidsense.drivers.recording.reader import RecordingReader
from support.cli import run_cli
from support.harness import REPO
from support.recording import record, the_file


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("plot")

    async def two(ctrl):
        await ctrl.run_cycle(store_reference=True)
        await ctrl.scene.place(CylinderScene(diameter_mm=60))
        return [await ctrl.run_cycle(label="D60")]

    record(tmp, two)
    return the_file(tmp)


def test_the_plotted_data_are_the_recordings(recorded, tmp_path):
    plots = read_cycles(recorded)
    assert [p.cycle_id for p in plots] == [1, 2]
    t, p, cycles = [], [], {}
    with RecordingReader(recorded) as reader:
        for rec in reader.records():
            if rec.topic == "samples":
                t.append(rec.data.t)
                p.append(rec.data.values[:, rec.data.channels.index("p_act")])
            elif rec.topic == "cycle":
                cycles[rec.data["cycle_id"]] = rec.data
    t, p = np.concatenate(t), np.concatenate(p)
    fig = plot_cycles(plots, tmp_path / "all.png")
    assert (tmp_path / "all.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for ax, cp in zip(fig.axes, plots):
        r = cycles[cp.cycle_id]
        sel = (t >= r["t_start_s"]) & (t <= r["t_end_s"])
        line = ax.lines[0]  # the pressure, as drawn
        assert np.array_equal(line.get_xdata(), t[sel] - r["t_open_s"])
        assert np.allclose(line.get_ydata(), p[sel] / 1e3, rtol=0, atol=1e-12)
        assert ax.get_title().startswith(f"cycle {cp.cycle_id}") and f"P_eq {r['p_eq_kpa']:.3f}" in ax.get_title()
        spans = [(w["start_s"], w["end_s"]) for w in r["windows"]]
        assert [(s, e) for _, s, e in cp.windows] == spans and spans
    # the object's cycle is drawn with the free-air reference made by the first cycle
    ref_cycle, obj = plots
    assert ref_cycle.ref_kpa is None and obj.ref_kpa is not None
    first_open = (ref_cycle.t_rel_s >= 0) & (ref_cycle.t_rel_s < 20.0)  # the profile's actuate_s
    assert np.allclose(obj.ref_kpa - cycles[2]["offset_kpa"],
                       ref_cycle.p_kpa[first_open] - cycles[1]["offset_kpa"], atol=1e-9)
    assert cycles[2]["has_reference"] and "dP" in obj.title()


def test_plot_command_one_cycle_and_a_missing_one(recorded, tmp_path, capsys):
    out = tmp_path / "c2.png"
    ok = run_cli(capsys, "plot", recorded, "--cycle", "2", "--out", out, cwd=REPO)
    assert ok.returncode == 0 and out.stat().st_size > 1000, ok.stderr
    bad = run_cli(capsys, "plot", recorded, "--cycle", "9", "--out", tmp_path / "x.png", cwd=REPO)
    assert bad.returncode == 2 and "no cycle 9" in bad.stderr and not (tmp_path / "x.png").exists()
    notfile = run_cli(capsys, "plot", tmp_path / "none.mcap", "--out", tmp_path / "y.png", cwd=REPO)
    assert notfile.returncode == 2 and "Traceback" not in notfile.stderr
