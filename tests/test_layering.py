"""Layering: fluidsense -> tasks -> controller -> drivers -> common; the bottom layer
imports nothing of ours; the simulator stands beside the drivers and only the sim driver's
adapter imports it (docs/architecture.md, decision 1)."""

from __future__ import annotations

import subprocess
import sys

from .conftest import REPO


def test_import_contracts_hold():
    run_linter = "import sys; from importlinter.cli import lint_imports_command; sys.exit(lint_imports_command())"
    out = subprocess.run([sys.executable, "-c", run_linter, "--no-cache"], cwd=REPO,
                         capture_output=True, text=True, timeout=120)
    assert "4 kept, 0 broken" in out.stdout, out.stdout + out.stderr
    assert out.returncode == 0


def test_controller_and_tasks_do_not_load_the_plant_or_ur_rtde_at_import():
    code = ("import sys, controller.service, controller.commands.server, tasks.size_survey, fluidsense.cli;"
            "bad = [m for m in sys.modules if m.startswith(('drivers.sim', 'simulator', 'rtde'))];"
            "print(bad); sys.exit(1 if bad else 0)")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
