"""Figure helpers: matplotlib without a screen, PNGs without timestamps (reproducible)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

plt.rcParams.update({"figure.dpi": 100, "savefig.dpi": 100, "font.size": 9, "axes.grid": True,
                     "grid.alpha": 0.3, "figure.autolayout": True})


def figure(ncols: int = 1, nrows: int = 1, width: float = 5.0, height: float = 3.4):
    return plt.subplots(nrows, ncols, figsize=(width * ncols, height * nrows), squeeze=False)


def save(fig, out_dir: Path, name: str) -> str:
    path = Path(out_dir) / name
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)
    return name
