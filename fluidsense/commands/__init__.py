"""Subcommands of ``fluidsense``. Each module has ``register(subparsers)``; add a module
here and to ``MODULES`` to add a command."""

from . import (
    bench,
    calibrate,
    check,
    clients,
    demo,
    design,
    keys,
    plot,
    replay,
    report,
    run,
    simcell,
    simserial,
    task,
    watchdog,
)

MODULES = [run, demo, clients, check, calibrate, design, report, task, simcell, simserial, watchdog, keys, bench, replay,
           plot]
