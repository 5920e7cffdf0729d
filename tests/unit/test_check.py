"""``fluidsense check``'s judgement of the delivered sampling rate, in this process: a busy
PC's shortfall is said and is not a problem; an idle PC's, or a box of another generation's,
is. (``fluidsense check`` against the emulated control box through the real drivers:
tests/system/test_check.py.)"""

from __future__ import annotations


def _judged(samples: int, missed: int, load: float | None) -> list[str]:
    """judge_rate on 3 s of wall time at 500 Hz (the figures a check prints), with the PC's
    load average per CPU as it was measured during them."""
    import numpy as np
    from fluidsense.cli.check.findings import Findings
    from fluidsense.cli.check.readings import Sampling, judge_rate

    out = Findings(lambda _line: None)
    s = Sampling(channels=("p_act",), values=np.zeros((samples, 1)), samples=samples, missed=missed, late=0,
                 wall_s=3.0, span_s=3.0, delays_s=np.zeros(0))
    judge_rate(s, 500.0, False, out, load)
    return [p.subject for p in out.problems]


def test_a_busy_pc_is_not_a_broken_link():
    # 446 of 500 samples/s (the figure of a shared 2-core machine), 10 % of the slots missed
    assert _judged(1338, 162, load=2.6) == []  # busy: said, not a problem
    assert _judged(1338, 162, load=0.3) == ["sampling"]  # an idle PC has no excuse
    assert _judged(1338, 162, load=None) == ["sampling"]  # unknown load: judged strictly
    # a CB3 (125 Hz) configured as e-Series: a quarter of the rate, whatever the load
    assert _judged(375, 1125, load=2.6) == ["sampling"]
    assert _judged(1500, 0, load=0.3) == []
