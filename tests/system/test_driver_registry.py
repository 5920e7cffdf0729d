"""A driver is one registry entry (drivers/registry.py): its config model names its backend
and answers what the commands ask of a cell, so nothing outside drivers/ switches on
``driver.kind``; the recording's format lives in one package (docs/architecture.md,
"Adding a driver" and "Recording").

(Its in-process tests: tests/unit/test_driver_registry.py.)
"""

from __future__ import annotations

import subprocess
import sys
from fluidsense.drivers.registry import ENTRIES
from support.harness import REPO


def test_reading_a_config_imports_no_backend():
    """The entries are pydantic only: loading a cell config (and building the CLI) imports
    no backend module, so no ur_rtde, pymodbus, nidaqmx, MCAP or simulated plant."""
    backends = [e.backend_module for e in ENTRIES]
    code = ("import sys, fluidsense.controller.config, fluidsense.cli;"
            f"bad = [m for m in sys.modules if m in {backends!r} or m.split('.')[0] in "
            "('rtde_receive', 'rtde_io', 'rtde_control', 'pymodbus', 'nidaqmx', 'mcap', 'serial')"
            " or m.startswith('fluidsense.simulator')]; print(bad); sys.exit(1 if bad else 0)")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
