"""Benchmarks: ``python -m lab bench NAME``. Each module in this package that defines
``NAME``, ``HELP``, ``register(parser)`` and ``run(args) -> int`` becomes a bench.
Benchmarks print figures (``--json`` for machines); they assert nothing about speed."""

from __future__ import annotations

import importlib
import pkgutil
from types import ModuleType


def discover() -> dict[str, ModuleType]:
    found: dict[str, ModuleType] = {}
    for info in pkgutil.iter_modules(__path__):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        if hasattr(module, "NAME") and hasattr(module, "run"):
            found[module.NAME] = module
    return dict(sorted(found.items()))
