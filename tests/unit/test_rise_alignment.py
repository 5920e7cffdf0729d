"""A valve opened a few ms later than commanded (a polled driver's command latency) must not
read as contact: with ``sequence.align_rise_kpa`` (by default 'auto') each cycle is lined up
with the free-air reference on its first rise before dP is taken, in the cycle's analysis
and in the gripper's live contact watch, and an object needs the equilibrium and the
contact time to agree (analysis.judge_object). Analytic curves: a first-order rise to
35 kPa with a 0.1 s time constant at 500 Hz (the quick PneuNet gripper's rise), 0.5 kPa
contact threshold."""

from __future__ import annotations

import numpy as np
import pytest
from fluidsense.common.errors import ConfigError
from fluidsense.common.hardware import TankCircuit
from fluidsense.common.units import KPA
from fluidsense.controller.config import SequenceConfig, validate
from fluidsense.controller.cycles import features as F
from fluidsense.controller.cycles.analysis import Reference, alignment, analyse, object_bound
from fluidsense.controller.requests.grip_watch import ContactWatch

FS = 500.0
T_OPEN = 3.0
P_INF, TAU = 35 * KPA, 0.1


def rise(t_rel: np.ndarray, late_s: float = 0.0, contact_at_s: float | None = None,
         contact_kpa: float = 2.0, released_at_s: float | None = None) -> np.ndarray:
    """Offset-free actuator pressure; the valve really opens ``late_s`` after t_rel = 0;
    a contact from ``contact_at_s`` (on the valve's own timing) adds ``contact_kpa`` over
    0.05 s, and takes it away again from ``released_at_s`` (something brushed the fingers)."""
    tv = np.clip(t_rel - late_s, 0.0, None)
    p = P_INF * (1 - np.exp(-tv / TAU))
    if contact_at_s is not None:
        p = p + contact_kpa * KPA * (1 - np.exp(-np.clip(tv - contact_at_s, 0.0, None) / 0.05))
    if released_at_s is not None:
        p = p - contact_kpa * KPA * (1 - np.exp(-np.clip(tv - released_at_s, 0.0, None) / 0.05))
    return p


def cycle(late_s: float, contact_at_s: float | None = None, **kw) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(int(FS * (T_OPEN + 3.0))) / FS
    p = np.where(t < T_OPEN, 0.0, rise(t - T_OPEN, late_s, contact_at_s, **kw))
    return t, p[:, None]


def sequence(align: list[float] | str | None = "auto") -> SequenceConfig:
    return SequenceConfig(charge_s=1.0, isolate_s=2.0, actuate_s=3.0, vent_s=1.0, offset_s=0.4,
                          windows=[{"name": "eq", "start_s": 2.0, "end_s": 2.5}], align_rise_kpa=align)


# the reference was taken while the PC was busy: its valve opened 6 ms after the command
REF_LATE = 0.006
REFERENCE = Reference(np.arange(int(3.0 * FS)) / FS, rise(np.arange(int(3.0 * FS)) / FS, REF_LATE), cycle_id=1)


def run(late_s: float, align: list[float] | str | None, contact_at_s: float | None = None, **kw):
    t, values = cycle(late_s, contact_at_s, **kw)
    return analyse(2, 63 * KPA, 0.0, T_OPEN, None, t, values, ("p_act",), sequence(align), REFERENCE,
                   circuit=TankCircuit())


def test_rise_shift_is_the_delay_between_the_two_rises():
    t_rel = np.arange(int(FS)) / FS
    for late in (0.0, 0.003, 0.009, 0.0131):
        shift = F.rise_shift(t_rel, rise(t_rel, late), REFERENCE.t_rel, REFERENCE.p, 1 * KPA, 3 * KPA)
        assert shift == pytest.approx(late - REF_LATE, abs=1e-4)
    # a curve that never reaches the upper level has no shift
    assert F.rise_shift(t_rel, 0.5 * KPA * np.ones_like(t_rel), REFERENCE.t_rel, REFERENCE.p, 1 * KPA, 3 * KPA) is None


@pytest.mark.parametrize("align", [[1.0, 3.0], "auto"])
def test_a_valve_timed_differently_from_the_reference_reads_as_contact_unless_aligned(align):
    plain = run(0.0, None)  # on time: ahead of the reference's rise, dP > 0 on the way up
    assert plain.t_c_threshold is not None and plain.t_c_threshold < 0.05
    aligned = run(0.0, align)
    assert aligned.rise_shift == pytest.approx(-REF_LATE, abs=2e-4)
    assert aligned.t_c_threshold is None and abs(aligned.dp_max) < 0.05 * KPA
    assert aligned.object is False and aligned.object_note is None
    # the window features do not depend on the timing of the rise
    assert aligned.p_eq == pytest.approx(plain.p_eq)


def test_auto_alignment_is_the_default_and_takes_its_levels_from_the_reference():
    assert SequenceConfig().align_rise_kpa == "auto"
    a = alignment(sequence(), REFERENCE, 1.0)
    # lo: 2 % of the reference's 35 kPa (its noise is zero here); hi: 8 % at least, and
    # where the reference is 8 samples after lo (this rise passes 2-8 % in 5 samples)
    t_lo = REF_LATE - TAU * np.log(1 - 0.02)
    assert a.lo == pytest.approx(0.7 * KPA)
    assert a.hi == pytest.approx(rise(np.array([t_lo + 8 / FS]), REF_LATE)[0], rel=0.02) and a.hi > 2.8 * KPA
    # no contact time before the rise is slow enough that one sample period of timing is
    # worth at most half the 0.5 kPa threshold: 35 kPa / 0.1 s x exp(-t / 0.1) x 2 ms <= 0.25 kPa
    assert a.t_min == pytest.approx(REF_LATE + TAU * np.log(35 / TAU * (1 / FS) / 0.25), abs=2 / FS)
    assert a.t_min > t_lo + 8 / FS
    # sampled at 5 kHz the same rise keeps 8 %: 8 samples there are 1.6 ms
    fine = Reference(np.arange(15000) / 5000, rise(np.arange(15000) / 5000, REF_LATE), 1)
    assert alignment(sequence(), fine, 1.0).hi == pytest.approx(2.8 * KPA)
    assert alignment(sequence(None), REFERENCE, 1.0) is None
    # a noisy reference: the levels keep 5 and 10 times its noise in the first window
    noisy = Reference(REFERENCE.t_rel, REFERENCE.p + np.random.default_rng(1).normal(0, 0.3 * KPA, 1500), 1)
    a = alignment(sequence(), noisy, 1.0)
    sd = float(np.std(noisy.p[(noisy.t_rel >= 2.0) & (noisy.t_rel < 2.5)]))
    assert a.lo == pytest.approx(5 * sd) and a.hi >= 10 * sd
    # a rise too small to align on (the levels would reach past 30 % of it): none, said by None
    flat = Reference(REFERENCE.t_rel, REFERENCE.p / 35 * 0.4 + np.random.default_rng(2).normal(0, 0.02 * KPA, 1500), 1)
    assert alignment(sequence(), flat, 1.0) is None


@pytest.mark.parametrize("align", [[1.0, 3.0], "auto"])
def test_a_real_contact_is_found_at_the_same_time_on_the_reference_timing(align):
    on_time = run(0.0, align, contact_at_s=0.2)
    late = run(0.008, align, contact_at_s=0.2)
    assert on_time.t_c_threshold is not None and 0.2 < on_time.t_c_threshold < 0.3
    assert late.t_c_threshold == pytest.approx(on_time.t_c_threshold, abs=1e-3)
    assert late.dp_max == pytest.approx(on_time.dp_max, rel=0.01)
    assert on_time.object is True and late.object is True


def test_an_object_needs_an_equilibrium_clear_of_the_free_air_spread():
    circuit = TankCircuit()  # the paper's regulator: 0.08 kPa from one charge to the next
    bound = object_bound(sequence(), circuit, 35 * KPA, 63 * KPA)
    assert bound == pytest.approx(4 * np.sqrt(2) * 0.08 * 35 / 63 * KPA)  # 4 sd of a difference of two cycles
    assert object_bound(sequence().model_copy(update={"eq_sd_kpa": 0.1}), circuit, 35 * KPA, 63 * KPA) == \
        pytest.approx(4 * np.sqrt(2) * 0.1 * KPA)  # the rig's own figure, where it is stated
    # a contact that is gone again by the window (the fingers brushed something): the
    # features disagree, and the answer says so instead of guessing
    brushed = run(0.0, "auto", contact_at_s=0.2, released_at_s=0.5)
    assert brushed.t_c_threshold is not None and abs(brushed.dp_eq) < bound
    assert brushed.object is None and "disagree" in brushed.object_note
    # a small object whose dP stays under the contact threshold but clear of the spread
    small = run(0.0, "auto", contact_at_s=0.2, contact_kpa=0.4)
    assert small.t_c_threshold is None and small.dp_eq > bound and small.object is True
    # an equilibrium far below the reference's: the reference is not this cycle's
    below = run(0.0, "auto", contact_at_s=0.2, contact_kpa=-1.0)
    assert below.object is None and "below the free-air reference" in below.object_note


def test_no_contact_time_before_the_reference_has_risen_through_the_levels():
    """Something already touching as the valve opens changes the first rise: dP says
    nothing about it there, and the equilibrium still tells the object."""
    early = run(0.0, "auto", contact_at_s=0.0, contact_kpa=3.0)
    a = alignment(sequence(), REFERENCE, 1.0)
    assert early.t_c_min == pytest.approx(a.t_min)
    assert early.t_c_threshold is None or early.t_c_threshold >= a.t_min
    assert early.object is True


def test_a_rise_with_samples_missing_across_the_levels_is_not_aligned_and_claims_no_contact():
    """A busy PC missed 30 ms of slots on the rise: the crossing times there are guesses."""
    t, values = cycle(0.0)
    rel = t - T_OPEN
    keep = ~((rel > 0.003) & (rel < 0.035))
    res = analyse(2, 63 * KPA, 0.0, T_OPEN, None, t[keep], values[keep], ("p_act",), sequence(), REFERENCE,
                  circuit=TankCircuit())
    assert res.rise_shift is None and res.t_c_threshold is None
    assert res.object is False and "could not be aligned" in res.object_note


def stale(t_rel: np.ndarray, p: np.ndarray, at: list[int], hold: int) -> np.ndarray:
    """Samples ``at`` (indices) and the ``hold - 1`` after each answer with the value read at
    the first of them: a polled box that did not refresh its register for ``hold`` periods."""
    q = p.copy()
    for k in at:
        q[k:k + hold] = p[k]
    return q


def test_one_stale_sample_on_the_rise_does_not_move_the_shift():
    """A box that refreshed late once on the rise: one level's crossing is off by up to a
    period; the median of the levels is not."""
    t_rel = np.arange(int(FS)) / FS
    p = rise(t_rel, 0.0)
    k = int(np.flatnonzero(p > 1.6 * KPA)[0])
    shift = F.rise_shift(t_rel, stale(t_rel, p, [k], 2), REFERENCE.t_rel, REFERENCE.p, 1 * KPA, 3 * KPA, levels=7)
    assert shift == pytest.approx(-REF_LATE, abs=2e-4)


def test_a_rise_whose_levels_disagree_is_not_aligned():
    """Stale values across most of the rise (a box busy for several periods, again and again):
    the levels' shifts spread by more than a period, and no one shift is claimed."""
    t_rel = np.arange(int(FS)) / FS
    p = rise(t_rel, 0.0)
    ks = np.flatnonzero((p > 0.9 * KPA) & (p < 3.2 * KPA))
    bad = stale(t_rel, p, list(range(int(ks[0]), int(ks[-1]) + 1, 4)), 4)
    assert F.rise_shift(t_rel, bad, REFERENCE.t_rel, REFERENCE.p, 1 * KPA, 3 * KPA, levels=7) is None
    # the same curve without the stale values lines up
    assert F.rise_shift(t_rel, p, REFERENCE.t_rel, REFERENCE.p, 1 * KPA, 3 * KPA, levels=7) == pytest.approx(
        -REF_LATE, abs=1e-4)


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


@pytest.mark.parametrize("align", [None, [1.0, 3.0], "auto"])
def test_the_live_contact_watch_lines_up_the_same_way(align):
    def watch():
        return ContactWatch(REFERENCE, 0.5 * KPA, 1.0, 0.4, 2.5, alignment(sequence(align), REFERENCE, 1.0))

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


def test_auto_keeps_the_commanded_timing_only_where_the_valves_switch_on_the_samples_clock(tmp_path):
    """A simulated cell in virtual time switches a valve at the sample time its command
    names: cycles and references are timed alike, and the cell's profile keeps that timing.
    Everywhere else (the emulated or a real box, a serial board, a real-time simulated cell)
    the command reaches the valve when the host gets round to it: auto stays auto."""
    from fluidsense.controller.config import load_cell_config
    from support.harness import CONFIG, sim_config, simcell_config

    assert load_cell_config(sim_config(tmp_path)).profile.sequence.align_rise_kpa is None
    assert load_cell_config(sim_config(tmp_path, clock="realtime")).profile.sequence.align_rise_kpa == "auto"
    for kind in ("modbus", "ur"):
        cfg = load_cell_config(simcell_config(tmp_path, kind, "127.0.0.9"))
        assert cfg.profile.sequence.align_rise_kpa == "auto", kind
    # levels set by hand are the profile's, whatever the driver
    quick = load_cell_config(sim_config(tmp_path, profile=str(CONFIG / "profiles" / "pneunet-gripper-quick.yaml")))
    assert quick.profile.sequence.align_rise_kpa == (1.0, 3.0)
