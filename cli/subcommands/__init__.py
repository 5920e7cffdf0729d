"""Subcommands of ``fluidsense``. Each module has ``register(subparsers)``; add a module
here and to ``MODULES`` to add a command. The studies (bench, report, simserial) are not
here: they live in the repository's ``lab/`` (``python -m lab``), outside the wheel."""

from . import (
    calibrate,
    characterise,
    chart,
    check,
    clients,
    demo,
    design,
    init,
    keys,
    plot,
    replay,
    run,
    simcell,
    task,
    watchdog,
)

MODULES = [run, demo, clients, init, check, calibrate, characterise, design, chart, task, simcell, watchdog, keys, replay,
           plot]
