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
