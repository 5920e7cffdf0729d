"""The residual-pressure protocol's runs, for its tests in both tiers."""

from __future__ import annotations

import asyncio

from fluidsense.common.budget import PartsBudget
from fluidsense.controller.config import CellConfig, load_profile
from fluidsense.daemon import app
from fluidsense.drivers.registry import Perturbations, SimDriverConfig

from support.harness import CONFIG


def run_profile(profile: str, body, seed: int = 3, residual_kpa: float = 0.0, parts: dict | None = None,
                **sequence):
    """Run ``body(controller)`` on a virtual-time simulated cell of the shipped ``profile``
    (``sequence`` overrides its sequence; ``parts`` its parts, e.g. ``{"circuit": {...},
    "sensor": {...}}``; ``residual_kpa`` leaves that much in the tube)."""
    # the protocol is about the tube, not the parts: without the profile's error budget the
    # sensor's offset is its fixed one (a session's zero draw would move it within the TEB)
    prof = load_profile(CONFIG / "profiles" / f"{profile}.yaml").model_copy(update={"budget": PartsBudget()})
    if parts:
        prof = prof.model_copy(update={name: getattr(prof, name).model_copy(update=u) for name, u in parts.items()})
    if sequence:
        prof = prof.model_copy(update={"sequence": prof.sequence.model_copy(update=sequence)})
    cfg = CellConfig(driver=SimDriverConfig(clock="virtual", seed=seed,
                                            perturb=Perturbations(residual_kpa=residual_kpa)), profile=prof)

    async def main():
        async with app.controller(cfg) as ctrl:
            return await body(ctrl)

    return asyncio.run(main())
