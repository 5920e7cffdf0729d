"""The tank circuit's characterisation against hidden actuators, for its tests in both
tiers: a hidden profile (free volume and compliance drawn 0.85-1.15 x the shipped) and its
cycles run in process, in virtual time, with the shipped profile driving them."""

from __future__ import annotations

import asyncio

import numpy as np
from fluidsense.controller.config import load_cell_config, load_profile
from fluidsense.controller.service import Controller
from fluidsense.drivers.registry import build_backend
from fluidsense.tasks import characterise as ch
from fluidsense.tasks.journal import journal_path

from support.configs import profile_config
from support.harness import sim_config

START = "pneunet-gripper-quick"  # the shipped profile a user starts from: 6 s cycles, laminar circuit
LEVELS = 5
CYCLES = 4


def hidden_factors(seed: int) -> tuple[float, float]:
    """The hidden actuator of set-up ``seed``: free volume and compliance each 0.85-1.15
    times the shipped profile's (drawn, not chosen to pass)."""
    rng = np.random.default_rng(1000 + seed)
    return float(rng.uniform(0.85, 1.15)), float(rng.uniform(0.85, 1.15))


def hidden_profile(tmp_path, seed: int, start=START, **extra):
    shipped = load_profile(profile_config(tmp_path, start))
    fv, fc = hidden_factors(seed)
    actuator = {"v0_ml": round(shipped.actuator.v0_ml * fv, 4),
                "compliance_ml_per_kpa": round(shipped.actuator.compliance_ml_per_kpa * fc, 5)}
    return profile_config(tmp_path, start, actuator=actuator, **extra), actuator


def measure_hidden(tmp_path, seed: int, plant_path, start, levels, cycles: int, out: str | None = None):
    """The starting profile runs the cycles of ``levels`` x ``cycles`` on the simulated plant
    of the hidden profile at ``plant_path`` (the controller never sees it), in virtual time;
    the journal's entries (``out``'s journal, default out-SEED.yaml)."""
    hidden_cfg = load_cell_config(sim_config(tmp_path, seed=seed, profile=str(plant_path)))
    cfg = hidden_cfg.model_copy(update={"profile": start})
    levels = ch.check_plan(start, levels, cycles)
    journal = ch.CharacteriseJournal.open(journal_path(tmp_path / (out or f"out-{seed}.yaml")),
                                          {"levels_kpa": levels, "cycles": cycles}, resume=False)

    async def main():
        ctrl = Controller(cfg, build_backend(cfg.driver, hidden_cfg.profile.hardware))
        await ctrl.start()
        try:
            return await ch.measure(ctrl.task_port, levels, cycles, journal)
        finally:
            await ctrl.stop()

    return asyncio.run(main())


def characterise_in_process(tmp_path, seed: int, plant_profile_path, levels=None, cycles=CYCLES):
    """The shipped profile (START) runs the cycles on the hidden profile's plant: (the
    starting profile, the journal's entries)."""
    start = load_profile(profile_config(tmp_path, START))
    return start, measure_hidden(tmp_path, seed, plant_profile_path, start,
                                 levels or ch.default_levels(start, LEVELS), cycles)
