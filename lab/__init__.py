"""The studies: benchmarks, the reproduction report, fuzzing and the serial board's
firmware behind a pty. They live in the repository beside the product and are not in its
wheel (the wheel carries what a cell runs). Run them from a checkout with the project
installed (``make install``): ``python -m lab --help``; the Makefile's targets (``make
report``, ``make speed-accuracy``, ``make fuzz``, ...) call them.

Inside ``lab`` imports are ``lab.*``; the product is imported as ``fluidsense.*`` and
never imports ``lab`` (an import contract in pyproject.toml)."""

from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
CONFIG = REPO / "config"
