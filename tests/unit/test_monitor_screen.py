"""``fluidsense monitor``'s view drawn from messages in this process: pressure, results, a
fault and what to do about it, another daemon, a stopped one. (The monitor in a real pseudo-
terminal against a real daemon, and what `cmd` and `monitor` say when nothing answers:
tests/system/test_monitor_screen.py.)"""

from __future__ import annotations

import re
from fluidsense.cli.screen import View, render, sparkline


def test_the_view_shows_pressure_results_and_what_to_do_about_a_fault():
    v = View()
    assert "waiting for the daemon at ipc://x" in render(v, "ipc://x", None)[0]
    v.take("pressure", {"seq": 1, "t_s": 1.0, "channels": ["p_act", "p_tank"], "units": ["kPa", "kPa"],
                        "times_s": [0.998, 0.999, 1.0], "values": [[1.0, 2.0, 3.5], [50.0, 50.0, 49.0]]})
    v.take("state", {"seq": 2, "t_s": 1.0, "cycle_id": 4, "from": "idle", "to": "charge", "reason": "command"})
    v.take("cycle", {"seq": 5, "t_s": 2.0, "cycle_id": 4, "ok": True, "p_eq_kpa": 34.25, "p_sd_kpa": 0.01,
                     "dp_eq_kpa": 1.5, "t_c_threshold_s": None, "label": "cyl60"})
    v.take("fault", {"seq": 6, "t_s": 2.1, "kind": "leak", "detail": "falls 3 kPa/s", "vented": True})
    text = "\n".join(render(v, "ipc://x", None))
    assert "state CHARGE" in text and "cycle 4" in text
    assert re.search(r"p_act\s+3\.50 kPa", text) and re.search(r"p_tank\s+49\.00 kPa", text)
    assert "cycle 4 cyl60: P_eq 34.250 ± 0.020 kPa (95 %), dP 1.500 kPa" in text
    assert "FAULT leak: falls 3 kPa/s" in text and "check the tubing" in text
    assert v.missed_messages == 2  # seq 3 and 4 never arrived
    assert sparkline([0.0, 1.0]) == "▁█" and sparkline([]) == ""


def test_the_view_starts_afresh_for_another_daemon_and_shows_a_stopped_one_as_gone():
    v = View()
    v.take_welcome("a" * 16)
    v.take("heartbeat", {"instance": "a" * 16, "seq": 9, "t_s": 122.529, "state": "idle", "cycle_id": 7,
                         "samples": 122529, "missed": 0, "late": 0, "block_proc_us": {"p99": 20.0}})
    v.take("cycle", {"instance": "a" * 16, "seq": 10, "t_s": 122.5, "cycle_id": 7, "ok": True, "p_eq_kpa": 34.25,
                     "p_sd_kpa": 0.01, "label": None})
    v.take("log", {"instance": "a" * 16, "seq": 11, "t_s": 122.6, "level": "INFO", "message": "controller stopped"})
    text = "\n".join(render(v, "ipc://x", "ipc://y"))
    assert f"the daemon {'a' * 16}: stopped; its state is not known (last heard at t 122.600 s)" in text, text
    assert "state IDLE" not in text and "122529 samples" not in text and "cycle 7: P_eq" in text, text
    # a new daemon on the same endpoints: its status reply, then its heartbeat; nothing old is mixed in
    v.take_status({"instance": "b" * 16, "state": "idle", "cycle_id": 0, "t_s": 0.2})
    v.take("heartbeat", {"instance": "b" * 16, "seq": 1, "t_s": 1.0, "state": "idle", "cycle_id": 0,
                         "samples": 1000, "missed": 0, "late": 0, "block_proc_us": {"p99": 20.0}})
    text = "\n".join(render(v, "ipc://x", "ipc://y"))
    assert "t     1.000 s   state IDLE   cycle 0" in text and f"daemon {'b' * 16}" in text, text
    assert "loop: 1000 samples" in text and "cycle 7" not in text and "none yet" in text, text
    assert v.missed_messages == 0  # seq starting again at 1 is no loss
