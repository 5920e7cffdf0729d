"""The kept free-air reference's file, read in this process: a changed P0 has no reference at
its P0, and a garbled or foreign file is refused with the reason
(controller/cycles/kept.py). (A daemon killed and started again with the reference it kept:
tests/system/test_kept_reference.py.)"""

from __future__ import annotations

import json

from fluidsense.controller.config import load_cell_config
from fluidsense.controller.cycles.kept import KIND, ReferenceKeeper, identity
from support.configs import profile_config
from support.harness import PROFILE, sim_config

P0_KPA = 63.0  # the pneunet gripper's


def test_a_changed_p0_has_no_reference_at_its_p0_and_other_parts_are_named(tmp_path):
    """P0 is each reference's key: one kept at 63 kPa still serves cycles at 63 kPa, not a
    profile whose P0 became 60 kPa. Every other part of the identity refuses it by name."""
    cfg = load_cell_config(sim_config(tmp_path))
    lower = load_cell_config(sim_config(tmp_path, profile=str(profile_config(tmp_path, PROFILE,
                                                                             sequence={"p0_kpa": 60.0}))))
    assert identity(lower) == identity(cfg)  # the same cell: only the default P0 moved
    slower = load_cell_config(sim_config(tmp_path, profile=str(profile_config(tmp_path, PROFILE,
                                                                              sequence={"charge_s": 12.0}))))
    faster = load_cell_config(sim_config(tmp_path, driver={"rate_hz": 500}))
    for other, part in ((slower, "sequence"), (faster, "driver")):
        assert [p for p in identity(cfg) if identity(cfg)[p] != identity(other)[p]] == [part]
    # a kept file with a reference at 63 kPa, read by the 60 kPa profile's daemon: kept, at 63 kPa only
    path = tmp_path / "refs.json"
    keeper = ReferenceKeeper(path, identity(cfg))
    from fluidsense.controller.cycles.analysis import Reference
    import numpy as np

    keeper.add(P0_KPA * 1e3, P0_KPA, Reference(np.array([0.0, 0.001]), np.array([0.0, 10.0]), 3))
    keeper.write(keeper.snapshot())
    back = ReferenceKeeper(path, identity(lower))
    assert list(back.load()) == [P0_KPA] and back.refused == []
    assert ReferenceKeeper(path, identity(slower)).load() == {}


def test_a_garbled_or_foreign_file_is_refused_with_the_reason_and_nothing_else_happens(tmp_path):
    cfg = load_cell_config(sim_config(tmp_path))
    path = tmp_path / "refs.json"
    for text, reason in (("{not json", "Expecting property name"), ('{"kind": "something else"}', "not a file of"),
                         (json.dumps({"kind": KIND, "version": 1, "references": [{"p0_kpa": "63"}]}), "identity")):
        path.write_text(text)
        keeper = ReferenceKeeper(path, identity(cfg))
        assert keeper.load() == {}
        assert reason in (keeper.error or "") + json.dumps(keeper.refused), (text, keeper.error, keeper.refused)
    path.unlink()
    path.mkdir()  # not a regular file
    keeper = ReferenceKeeper(path, identity(cfg))
    assert keeper.load() == {} and "not a regular file" in keeper.error
