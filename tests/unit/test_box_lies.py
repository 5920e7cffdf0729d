"""The driver's timestamp guard on its own: late and slightly slow or fast clocks pass, what no
clock can do is refused. (A control box that lies on the wire, against the real drivers and
daemon: tests/system/test_box_lies.py.)"""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.timeout(300)


def test_the_timestamp_guard_takes_late_and_slightly_slow_or_fast_clocks_and_refuses_what_cannot_be():
    """The RTDE timestamp's bounds on their own, host times given: a box whose first packet
    is read 0.8 s late, whose packets then stop for 2 s (a stalled reader: the newest packet
    does not change, which the poller counts as missed, not checked) and whose clock runs
    1 % fast is sane; a step back, a jump ahead or a clock ten times fast is not, each
    naming ``timestamp``."""
    from fluidsense.common.errors import DeviceProtocolError
    from fluidsense.drivers.ur.poller import LEAD_MARGIN_S, TimestampGuard

    sane = TimestampGuard()
    sane.check(1234.0 - 0.8, 0.0)
    for k in [*range(1, 2000), *range(3000, 5000)]:  # 10 s at 500 Hz, no new packet for 2 s
        sane.check(1234.0 + k * 0.002 * 1.01, k * 0.002)
    cases = {"back": [(10.0, 0.0), (10.002, 0.002), (9.5, 0.004)],
             "ahead": [(10.0, 0.0), (10.002, 0.002), (10.002 + 2 * LEAD_MARGIN_S, 0.004)],
             "fast": [(10.0 + k * 0.02, k * 0.002) for k in range(100)],
             "nan": [(10.0, 0.0), (float("nan"), 0.002)]}
    for name, steps in cases.items():
        guard = TimestampGuard()
        with pytest.raises(DeviceProtocolError, match="^timestamp: ") as err:
            for stamp, host in steps:
                guard.check(stamp, host)
        assert err.value.field == "timestamp", name
