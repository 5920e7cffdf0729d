"""Subcommands of ``fluidsense``. Each module has ``register(subparsers)``; add a module
here and to ``MODULES`` to add a command."""

from . import bench, calibrate, check, clients, demo, design, keys, plot, replay, report, run, simcell, task, watchdog

MODULES = [run, demo, clients, check, calibrate, design, report, task, simcell, watchdog, keys, bench, replay, plot]
