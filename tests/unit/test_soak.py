"""The soak benchmark, shortened: every sample reaches the pipeline with a slow
subscriber attached, and the report carries its figures (docs/soak.md has the 8 h run).

(Its tests with real peers: tests/system/test_soak.py.)
"""

from __future__ import annotations

import numpy as np
import pytest
from fluidsense.common.samples import SampleBlock

from lab.bench.soak import GapCounter


def block(seq: int, first_slot: int, n: int = 10, missed: int = 0) -> SampleBlock:
    t = (first_slot + np.arange(n)) / 1000.0
    return SampleBlock(seq, t, np.zeros((n, 1)), ("p_act",), missed=missed)


def test_the_gap_counter_sees_every_kind_of_loss():
    clean = GapCounter(1000.0)
    for k in range(5):
        clean.on_block(block(k + 1, 10 * k))
    assert (clean.samples, clean.lost, clean.duplicated, clean.block_gaps) == (50, 0, 0, 0)

    lossy = GapCounter(1000.0)
    lossy.on_block(block(1, 0))
    lossy.on_block(block(3, 20))  # a whole block skipped
    lossy.on_block(block(4, 32, n=8))  # two slots skipped between blocks
    lossy.on_block(block(5, 40, missed=3))  # the source reports three unfilled slots
    assert lossy.block_gaps == 1 and lossy.slot_gaps == 12 and lossy.missed == 3 and lossy.lost == 15
    assert lossy.duplicated == 0

    twice = GapCounter(1000.0)
    twice.on_block(block(1, 0))
    twice.on_block(block(2, 5))  # slots 5..9 again
    assert twice.duplicated == 5 and twice.lost == 0


def test_the_cycle_history_keeps_no_traces(virtual_controller):
    """The caller gets the trace; the controller's history of 100 results does not keep
    ~0.6 MB of samples each (found by the soak: +26 MB over two hours)."""

    async def body(ctrl):
        results = [await ctrl.run_cycle() for _ in range(2)]
        return results, list(ctrl.cycles.results)

    returned, kept = virtual_controller(body)
    assert all(r.trace is not None for r in returned)
    assert [r.trace for r in kept] == [None, None]
    assert [r.p_eq for r in kept] == pytest.approx([r.p_eq for r in returned])
