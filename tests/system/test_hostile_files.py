"""Files are untrusted input (issue 14, items 5-6; docs/cli.md "Errors in files").

Every hostile kind of config, profile, task and calibration file gives one line per
problem, ``FILE: field: reason`` (``FILE:LINE:COLUMN: ...`` where the problem has a place),
and exit code 2 through the real CLI, never a traceback and never a hang, before anything
is started. Recordings are in tests/unit/test_recording.py, the semantic checks at load in
tests/unit/test_config.py. A property-based fuzz of config files closes the file.

(Its in-process tests: tests/unit/test_hostile_files.py.)
"""

from __future__ import annotations

from lab.bench import fuzz_files


def test_the_fuzz_bench_counts_in_worker_processes():
    """fuzz_config_files at a small budget: every file accounted for, none crashes or hangs."""
    out = fuzz_files.fuzz_config_files(examples=60, seed=5)
    assert out["files"] == out["rejected_cleanly"] + out["loaded"] + out["crashes"] + out["hangs"]
    assert out["files"] >= 50 and out["rejected_cleanly"] > 0
    assert out["crashes"] == 0 and out["hangs"] == 0, out["examples_of_crashes"]
