"""`python -m lab bench suite-cpu` as a developer runs it, on a small test file of its own:
each test's CPU lands in its file's row, each process the tests start in its kind's row,
including one that ends with os._exit (as the sampler and the ur_rtde worker do)."""

from __future__ import annotations

import json
import subprocess
import sys

from support.harness import REPO

TESTS = '''
import subprocess, sys

def test_starts_the_cli():
    subprocess.run([sys.executable, "-m", "fluidsense", "--help"], check=True, capture_output=True)

def test_starts_a_process_that_ends_with_os_exit():
    subprocess.run([sys.executable, "-c", "import os; os._exit(0)"], check=True)

def test_works_in_the_worker():
    assert sum(i * i for i in range(3_000_000)) > 0
'''


def test_the_runs_cpu_is_told_per_file_and_per_kind_of_process(tmp_path):
    (tmp_path / "test_small.py").write_text(TESTS)
    out = subprocess.run([sys.executable, "-m", "lab", "bench", "suite-cpu", "--json", "--", str(tmp_path), "-n", "0"],
                         cwd=REPO, capture_output=True, text=True, timeout=240)
    assert out.returncode == 0, out.stderr
    res = json.loads(out.stdout)
    assert res["exit_code"] == 0 and res["tests"] == 3
    (row,) = res["files"]
    assert row["file"].endswith("test_small.py") and row["tests"] == 3
    kinds = {k["kind"]: k for k in res["kinds"]}
    assert kinds["fluidsense --help"]["n"] == 1 and kinds["fluidsense --help"]["cpu_s"] > 0
    assert kinds["-c import os; os._exit(0)"]["n"] == 1
    assert set(kinds) == {"fluidsense --help", "-c import os; os._exit(0)"}  # pytest itself is not a test's
    worker = {t["id"].split("::")[1]: t for t in res["slowest"]}
    # the sum runs in the worker; the CLI's CPU is in its test's child time, where it was reaped
    assert worker["test_works_in_the_worker"]["self_s"] > worker["test_works_in_the_worker"]["child_s"]
    assert worker["test_starts_the_cli"]["child_s"] >= kinds["fluidsense --help"]["cpu_s"]
    assert res["child_s"] >= res["started_reported_s"]
