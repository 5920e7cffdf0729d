"""A valve opened a few ms later than commanded (a polled driver's command latency) must not
read as contact: with ``sequence.align_rise_kpa`` each cycle is lined up with the free-air
reference on its first rise before dP is taken, in the cycle's analysis and in the gripper's
live contact watch. Analytic curves: a first-order rise to 35 kPa with a 0.1 s time
constant at 500 Hz (the quick PneuNet gripper's rise), 0.5 kPa contact threshold."""

from __future__ import annotations

import numpy as np
import pytest
from fluidsense.common.errors import ConfigError
from fluidsense.common.units import KPA
from fluidsense.controller.config import SequenceConfig, validate
from fluidsense.controller.cycles import features as F
from fluidsense.controller.cycles.analysis import Reference, analyse
from fluidsense.controller.requests.grip_watch import ContactWatch

FS = 500.0
T_OPEN = 3.0
P_INF, TAU = 35 * KPA, 0.1


def rise(t_rel: np.ndarray, late_s: float = 0.0, contact_at_s: float | None = None) -> np.ndarray:
    """Offset-free actuator pressure; the valve really opens ``late_s`` after t_rel = 0;
    a contact from ``contact_at_s`` (on the valve's own timing) adds 2 kPa over 0.05 s."""
    tv = np.clip(t_rel - late_s, 0.0, None)
    p = P_INF * (1 - np.exp(-tv / TAU))
    if contact_at_s is not None:
        p = p + 2 * KPA * (1 - np.exp(-np.clip(tv - contact_at_s, 0.0, None) / 0.05))
    return p


def cycle(late_s: float, contact_at_s: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(int(FS * (T_OPEN + 3.0))) / FS
    p = np.where(t < T_OPEN, 0.0, rise(t - T_OPEN, late_s, contact_at_s))
    return t, p[:, None]


def sequence(align: list[float] | None) -> SequenceConfig:
    return SequenceConfig(charge_s=1.0, isolate_s=2.0, actuate_s=3.0, vent_s=1.0, offset_s=0.4,
                          windows=[{"name": "eq", "start_s": 2.0, "end_s": 2.5}], align_rise_kpa=align)


# the reference was taken while the PC was busy: its valve opened 6 ms after the command
REF_LATE = 0.006
REFERENCE = Reference(np.arange(int(3.0 * FS)) / FS, rise(np.arange(int(3.0 * FS)) / FS, REF_LATE), cycle_id=1)


def run(late_s: float, align: list[float] | None, contact_at_s: float | None = None):
    t, values = cycle(late_s, contact_at_s)
    return analyse(2, 63 * KPA, 0.0, T_OPEN, None, t, values, ("p_act",), sequence(align), REFERENCE)


def test_rise_shift_is_the_delay_between_the_two_rises():
    t_rel = np.arange(int(FS)) / FS
    for late in (0.0, 0.003, 0.009, 0.0131):
        shift = F.rise_shift(t_rel, rise(t_rel, late), REFERENCE.t_rel, REFERENCE.p, 1 * KPA, 3 * KPA)
        assert shift == pytest.approx(late - REF_LATE, abs=1e-4)
    # a curve that never reaches the upper level has no shift
    assert F.rise_shift(t_rel, 0.5 * KPA * np.ones_like(t_rel), REFERENCE.t_rel, REFERENCE.p, 1 * KPA, 3 * KPA) is None


def test_a_valve_timed_differently_from_the_reference_reads_as_contact_unless_aligned():
    plain = run(0.0, None)  # on time: ahead of the reference's rise, dP > 0 on the way up
    assert plain.t_c_threshold is not None and plain.t_c_threshold < 0.05
    aligned = run(0.0, [1.0, 3.0])
    assert aligned.rise_shift == pytest.approx(-REF_LATE, abs=2e-4)
    assert aligned.t_c_threshold is None and abs(aligned.dp_max) < 0.05 * KPA
    # the window features do not depend on the timing of the rise
    assert aligned.p_eq == pytest.approx(plain.p_eq)


def test_a_real_contact_is_found_at_the_same_time_on_the_reference_timing():
    on_time = run(0.0, [1.0, 3.0], contact_at_s=0.2)
    late = run(0.008, [1.0, 3.0], contact_at_s=0.2)
    assert on_time.t_c_threshold is not None and 0.2 < on_time.t_c_threshold < 0.3
    assert late.t_c_threshold == pytest.approx(on_time.t_c_threshold, abs=1e-3)
    assert late.dp_max == pytest.approx(on_time.dp_max, rel=0.01)


def test_without_a_reference_nothing_is_aligned():
    t, values = cycle(0.0)
    res = analyse(2, 63 * KPA, 0.0, T_OPEN, None, t, values, ("p_act",), sequence([1.0, 3.0]), None)
    assert res.rise_shift is None and res.t_c_threshold is None and not res.has_reference


def feed_blocks(watch: ContactWatch, late_s: float, contact_at_s: float | None, block: int = 10) -> float | None:
    t, values = cycle(late_s, contact_at_s)
    for i in range(0, len(t), block):
        tc = watch.feed(t[i:i + block], values[i:i + block, 0], T_OPEN)
        if tc is not None:
            return tc
    return None


@pytest.mark.parametrize("align", [None, (1 * KPA, 3 * KPA)])
def test_the_live_contact_watch_lines_up_the_same_way(align):
    def watch():
        return ContactWatch(REFERENCE, 0.5 * KPA, 1.0, 0.4, 2.5, align)

    empty = feed_blocks(watch(), 0.0, None)
    touched = feed_blocks(watch(), 0.0, 0.2)
    if align is None:
        assert empty is not None and empty < 0.05  # the rise ahead of the reference's looks like contact
    else:
        assert empty is None
        assert touched is not None and 0.2 < touched < 0.3


@pytest.mark.parametrize("bad", [[3.0, 1.0], [0.0, 2.0], [1.0, 101.0]])
def test_alignment_levels_must_be_an_increasing_pair_of_small_pressures(bad, tmp_path):
    data = {"charge_s": 1.0, "isolate_s": 2.0, "actuate_s": 3.0, "offset_s": 0.4,
            "windows": [{"name": "eq", "start_s": 2.0, "end_s": 2.5}], "align_rise_kpa": bad}
    with pytest.raises(ConfigError, match="align_rise_kpa must be"):
        validate(SequenceConfig, data, tmp_path / "p.yaml")
