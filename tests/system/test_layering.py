"""Layering: cli -> daemon -> tasks -> controller -> drivers -> common; tasks hold the
controller's task port, never its service; the bottom layer imports nothing of ours; the
simulator stands beside the drivers and only the sim driver's adapter imports it; the client
knows only the shared vocabulary; the product never imports the studies
(docs/architecture.md, decision 1). Every import of ours names ``fluidsense``.

(Its in-process tests: tests/unit/test_layering.py.)
"""

from __future__ import annotations

import subprocess
import sys

from support.harness import REPO


def test_import_contracts_hold():
    run_linter = "import sys; from importlinter.cli import lint_imports_command; sys.exit(lint_imports_command())"
    out = subprocess.run([sys.executable, "-c", run_linter, "--no-cache"], cwd=REPO,
                         capture_output=True, text=True, timeout=120)
    assert "7 kept, 0 broken" in out.stdout, out.stdout + out.stderr
    assert out.returncode == 0


def test_controller_and_tasks_do_not_load_the_plant_or_ur_rtde_at_import():
    code = ("import sys, fluidsense.controller.service, fluidsense.controller.requests.server, "
            "fluidsense.tasks.size_survey, fluidsense.cli;"
            "bad = [m for m in sys.modules if m.startswith(('fluidsense.drivers.sim', 'fluidsense.simulator', 'rtde'))];"
            "print(bad); sys.exit(1 if bad else 0)")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
