"""fluidsense characterise on a tank circuit with an ISO 6358 valve (issue 36 item 1, "the
valve's conductance from the rise"): the sorting gripper's cell, whose hidden valve
conductance, free volume and compliance differ from the shipped profile by known
factors, characterised from the shipped profile in virtual time; the fitted C's 95 %
interval must cover the hidden one. Also: why b is kept (the rise's correlation of C and
b, and the residual against b: a profile likelihood), a b far from the kept one refused
by the residual, and a hose that dominates the rise keeping C.

(The fit: tasks/valve_rise.py. Each set-up is 20 cycles of 13 s of plant, virtual time,
and a fit of about 4 s: ten of them take about two minutes, hence this tier. Its in-process
half, where the rise cannot show C: tests/unit/test_characterise_iso.py.)
"""

from __future__ import annotations


import numpy as np
import pytest
from fluidsense.controller.config import load_profile
from fluidsense.controller.config.loading import read_yaml
from fluidsense.controller.config.profile import Profile
from fluidsense.tasks import characterise as ch
from fluidsense.tasks import valve_rise as vr
from support.characterise import measure_hidden
from support.configs import profile_config
from support.harness import REPO

START = "sorting-gripper"  # the product's main cell: 0.4 L tank, ISO 6358 valve, 3.3 m hose, sensor at the valve
HIDDEN_SETUPS = 10
LEVELS = 5
CYCLES = 4


def hidden_factors(seed: int) -> tuple[float, float, float]:
    """The hidden cell of set-up ``seed``: v0 and c each 0.85-1.15 times the shipped, the
    valve's C 0.7-1.3 times (drawn, not chosen to pass)."""
    rng = np.random.default_rng(3600 + seed)
    return float(rng.uniform(0.85, 1.15)), float(rng.uniform(0.85, 1.15)), float(rng.uniform(0.7, 1.3))


def hidden_profile(tmp_path, seed: int, **circuit):
    shipped = load_profile(profile_config(tmp_path, START))
    fv, fc, f_cond = hidden_factors(seed)
    actuator = {"v0_ml": round(shipped.actuator.v0_ml * fv, 4),
                "compliance_ml_per_kpa": round(shipped.actuator.compliance_ml_per_kpa * fc, 5)}
    cond = round(shipped.circuit.valve.sonic_conductance_dm3_per_s_bar * f_cond, 5)
    valve = {"sonic_conductance_dm3_per_s_bar": cond, **circuit.pop("valve", {})}
    path = profile_config(tmp_path, START, actuator=actuator, circuit={"valve": valve, **circuit})
    return path, {**actuator, "C": cond}


def characterise(tmp_path, seed: int, plant_path, start: Profile, levels=None, cycles=CYCLES):
    """The starting profile runs the cycles on the hidden profile's simulated plant (the
    controller never sees it), virtual time; the journal's entries."""
    return measure_hidden(tmp_path, seed, plant_path, start, levels or ch.default_levels(start, LEVELS), cycles)


def fitted(res, name):
    return next(f for f in res.fitted if f.field == name)


@pytest.mark.timeout(900)
def test_hidden_valve_conductances_are_recovered_within_their_intervals(tmp_path):
    """Ten hidden sorting cells (seeds 1-10: C 0.7-1.3 x the shipped 0.3 dm^3/(s bar), v0
    and c 0.85-1.15 x): the stated 95 % interval of C must cover the hidden C in at least 9
    of 10, and of the valve delay the plant's 12 ms likewise; the written profile carries C
    (b unchanged) with its provenance. An interval wider than +-10 % would say little about
    a C drawn over +-30 %, and fails."""
    start = load_profile(REPO / "config" / "profiles" / f"{START}.yaml")
    delay = start.circuit.valve_delay_s
    covered = {vr.C_FIELD: 0, vr.DELAY_FIELD: 0, "actuator.v0_ml": 0, "actuator.compliance_ml_per_kpa": 0}
    rows = []
    for seed in range(1, HIDDEN_SETUPS + 1):
        d = tmp_path / f"s{seed}"
        d.mkdir()
        path, hidden = hidden_profile(d, seed)
        entries = characterise(d, seed, path, start)
        res = ch.fit(entries, start)
        truth = {vr.C_FIELD: hidden["C"], vr.DELAY_FIELD: delay, "actuator.v0_ml": hidden["v0_ml"],
                 "actuator.compliance_ml_per_kpa": hidden["compliance_ml_per_kpa"]}
        for name in covered:
            f = fitted(res, name)
            covered[name] += f.lo95 <= truth[name] <= f.hi95
            rows.append((seed, name, truth[name], f.value, f.lo95, f.hi95))
        c = fitted(res, vr.C_FIELD)
        assert (c.hi95 - c.lo95) / 2 < 0.1 * c.value, (seed, c)
        assert vr.B_FIELD in res.kept and "cannot separate it from C" in res.kept[vr.B_FIELD]
        notes = [n for n in res.notes if n.startswith("ISO valve")]
        rows.append((seed, "notes", *notes))
        if seed == 1:  # the profile as the CLI writes it: C set in its nested field, b as it was
            data = ch.characterised_profile(read_yaml(REPO / "config" / "profiles" / f"{START}.yaml"), start, res,
                                            name="mine", rig="simulated", config="test", from_profile=START,
                                            levels=sorted({e["level_kpa"] for e in entries}), cycles=CYCLES,
                                            cycle_ids=[e["cycle_id"] for e in entries])
            mine = Profile.model_validate(data)
            assert mine.circuit.valve.sonic_conductance_dm3_per_s_bar == pytest.approx(c.value, rel=1e-5)
            assert mine.circuit.valve.critical_ratio == start.circuit.valve.critical_ratio
            assert vr.C_FIELD in {f.field for f in mine.provenance.fitted}
    lines = []
    for r in rows:
        if r[1] == "notes":
            lines.append(f"seed {r[0]}: " + "; ".join(r[2:]))
        else:
            s, n, t, v, lo, hi = r
            lines.append(f"seed {s} {n}: hidden {t:.4g}, fitted {v:.4g} [{lo:.4g}, {hi:.4g}]"
                         f"{'' if lo <= t <= hi else '  MISSED'}")
    summary = "\n".join(lines)
    print(f"\ncovered (of {HIDDEN_SETUPS}): {covered}\n{summary}")  # docs/cli.md quotes these (-s)
    assert all(n >= 9 for n in covered.values()), f"{covered}\n{summary}"


def test_b_is_not_separable_and_a_b_far_off_is_refused(tmp_path):
    """One hidden cell (seed 1), fitted with the kept b at 0.2, 0.3 (the plant's) and 0.4:
    the residual hardly moves while C absorbs b (the profile likelihood is flat within the
    sensor's noise: why b is kept); a plant whose b is 0.55 fitted with the kept 0.3 is
    refused by the residual, naming the critical ratio among the causes."""
    path, hidden = hidden_profile(tmp_path, 1)
    shipped = load_profile(REPO / "config" / "profiles" / f"{START}.yaml")
    entries = characterise(tmp_path, 1, path, shipped)
    rows = []
    for b in (0.2, 0.3, 0.4):
        d = tmp_path / f"b{b}"
        d.mkdir()
        start = load_profile(profile_config(d, START, circuit={"valve": {"critical_ratio": b}}))
        res = ch.fit(entries, start)
        rms = next(n for n in res.notes if n.startswith("ISO valve rise fit"))
        rows.append((b, fitted(res, vr.C_FIELD), rms))
    print("\nhidden C %.4g, b 0.3" % hidden["C"])
    for b, c, rms in rows:
        print(f"kept b {b}: C {c.value:.4g} [{c.lo95:.4g}, {c.hi95:.4g}]; {rms}")  # -s
    resid = [float(rms.split(", ")[1].split(" kPa")[0]) for _, _, rms in rows]
    noise = shipped.sensor.noise_sd_kpa
    # on this plant (the model exact) the residual is lowest at the plant's b, but +-0.1 of b
    # costs less than the sensor's noise twice over: a shape that the model's assumptions
    # outweigh on a rig (docs/cli.md: the fingers' assumed lag 30 ms off costs 0.28 kPa)
    assert resid[1] == min(resid) and max(resid) < 2 * noise, resid
    assert rows[0][1].value > rows[1][1].value > rows[2][1].value  # C takes b's place

    # what the model takes as stated weighs more than b: the fingers' lag (response_s,
    # assumed 0.05 s in the shipped profile) at 0.08 s on the plant, the shipped valve and
    # actuator otherwise (with seed 1's faster valve the lag shows more: 0.685 kPa, refused)
    d = tmp_path / "lag"
    d.mkdir()
    slow = profile_config(d, START, actuator={"response_s": 0.08})
    try:
        res = ch.fit(characterise(d, 3, slow, shipped), shipped)
        verdict = "holds"
    except ch.FitRefused as exc:
        res, verdict = exc.result, "refused"
    c = fitted(res, vr.C_FIELD)
    rms = next(n for n in res.notes if n.startswith("ISO valve rise fit"))
    print(f"plant response_s 0.08 s, kept 0.05: hidden C {shipped.circuit.valve.sonic_conductance_dm3_per_s_bar:.4g}"
          f", fitted {c.value:.4g} [{c.lo95:.4g}, {c.hi95:.4g}] ({verdict}); {rms}")  # -s
    assert float(rms.split(", ")[1].split(" kPa")[0]) > 3 * resid[1]  # the lag's shape shows, b's hardly

    d = tmp_path / "far"
    d.mkdir()
    far, _ = hidden_profile(d, 2, valve={"critical_ratio": 0.55})
    far_entries = characterise(d, 2, far, shipped, levels=[25.6, 44.8, 64.0], cycles=2)
    with pytest.raises(ch.FitRefused, match="does not follow the ISO 6358 valve's model.*critical ratio") as exc:
        ch.fit(far_entries, shipped)
    print(f"plant b 0.55, kept 0.3: {exc.value}")  # -s


def test_a_hose_that_dominates_the_rise_keeps_c(tmp_path):
    """A 12 m hose of 2.5 mm bore with the sensor at the actuator (both the hidden cell's and
    the starting profile's): the rise's times move less with C than with the hose's stated
    length, so C, b and the delay are kept, each said so, and the fit holds otherwise."""
    hose = {"hose": {"bore_mm": 2.5, "length_m": 12.0, "sensor_at": "actuator"}}
    path, _ = hidden_profile(tmp_path, 3, **hose)
    d = tmp_path / "start"
    d.mkdir()
    start = load_profile(profile_config(d, START, circuit=hose))
    res = ch.fit(characterise(tmp_path, 3, path, start, levels=[25.6, 44.8, 64.0], cycles=2), start)
    for name in (vr.C_FIELD, vr.B_FIELD, vr.DELAY_FIELD):
        assert res.kept[name].startswith("the hose dominates the rise"), res.kept
        assert name not in {f.field for f in res.fitted}
    print("\n" + res.kept[vr.C_FIELD])  # -s
