"""A recording made by a virtual-time controller."""

from __future__ import annotations

import asyncio
from pathlib import Path

from fluidsense.controller.config import CellConfig, load_cell_config
from fluidsense.daemon import app

from support.harness import sim_config


def cell(tmp_path: Path, **recording) -> CellConfig:
    cfg = load_cell_config(sim_config(tmp_path, clock="virtual"))
    return cfg.model_copy(update={"recording": cfg.recording.model_copy(update=recording)})


def the_file(tmp_path: Path) -> Path:
    files = sorted((tmp_path / "runs").glob("*.mcap"))
    assert len(files) == 1, files
    return files[0]


def record(tmp_path: Path, body, cfg: CellConfig | None = None, **recording):
    """Run ``body(controller)`` on a virtual-time controller that records (as the daemon)."""
    cfg = cfg or cell(tmp_path, **recording)

    async def main():
        async with app.controller(cfg, record=True) as ctrl:
            return await body(ctrl)

    return asyncio.run(main())
