"""What ``fluidsense monitor`` prints for a fault says what the device reported, not an assumption."""

from __future__ import annotations

import pytest
from fluidsense.cli.monitor import format_message


@pytest.mark.parametrize(("vented", "word"), [(True, "(vented)"), (False, "(NOT VENTED)"),
                                              ("unknown", "(vent not confirmed)"), (None, "(vent not confirmed)")])
def test_a_fault_line_says_whether_the_device_confirmed_the_vent(vented, word):
    msg = {"t_s": 1.0, "kind": "link_lost", "detail": "cable", "vented": vented}
    line = format_message("fault", msg)
    assert line is not None and line.endswith(word), line


def test_every_contact_time_shown_names_its_method():
    """A cycle carries two contact times that differ by design (slope change before the
    threshold crossing): the monitor's line, the screen's result line, the plot's title
    and replay's column each say which one they show."""
    import numpy as np
    from fluidsense.cli.plot import CyclePlot
    from fluidsense.cli.screen import result_line
    from fluidsense.cli.subcommands.replay import COLUMNS

    cycle = {"cycle_id": 3, "ok": True, "p0_kpa": 63.0, "p_eq_kpa": 36.3, "p_sd_kpa": 0.02, "dp_eq_kpa": 1.7, "label": "c60",
             "t_c_threshold_s": 0.107, "t_c_slope_s": 0.091}
    assert "t_c 0.107 s (threshold)" in format_message("cycle", cycle)
    assert "t_c 0.107 s (threshold)" in result_line(cycle)
    plot = CyclePlot(cycle_id=3, result=cycle, channel="p_act", t_rel_s=np.zeros(1), p_kpa=np.zeros(1))
    assert "t_c 0.107 s (threshold)" in plot.title()
    assert [title for key, title, _ in COLUMNS if key.startswith("t_c")] == ["t_c slope s"]
