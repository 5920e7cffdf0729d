"""Shared pieces of the report sections: running a profile, fitting, formatting."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from fluidsense.cli.options import PROFILES
from fluidsense.controller.config import Profile, load_profile
from fluidsense.controller.sensing.calibration import Calibration, feature_value
from fluidsense.controller.service import Controller
from fluidsense.tasks.experiments import sim_cell


@dataclass
class Section:
    """What one section contributes: Markdown, numbers (for results.json) and rows of the
    paper-versus-ours table."""

    key: str
    title: str
    markdown: str = ""
    numbers: dict[str, Any] = field(default_factory=dict)
    rows: list[dict[str, Any]] = field(default_factory=list)

    def row(self, quantity: str, paper: str, ours: str, match: bool | None, why: str, source: str, *,
            kind: str, tolerance: str = "") -> None:
        """One ledger row. ``paper``: the published value with its uncertainty; ``source``:
        where it is (figure/table/section of the published text); ``kind``: ``predicted``,
        or ``fitted: <parameter>`` when a model parameter was set from this very number (such
        a row agrees by construction and is never counted as a prediction); ``tolerance``:
        what "match" means for this row when the paper gives no uncertainty. ``match`` None:
        the paper states no number here (a qualitative claim, checked as stated in ``why``)."""
        if kind != "predicted" and not kind.startswith("fitted: "):
            raise ValueError(f"row kind must be 'predicted' or 'fitted: <parameter>', got {kind!r}")
        if match is False and not why:
            raise ValueError(f"mismatch without a reason: {quantity}")
        verdict = {True: "match", False: "mismatch", None: "qualitative"}[match]
        fitted = kind.startswith("fitted: ")
        self.rows.append({"quantity": quantity, "paper": paper, "ours": ours, "verdict": verdict,
                          "kind": "fitted" if fitted else "predicted",
                          "parameter": kind.removeprefix("fitted: ") if fitted else "",
                          "tolerance": tolerance, "why": why, "source": source})


def ledger_counts(rows: list[dict[str, Any]]) -> dict[str, int]:
    """The summary line: how many predicted rows agree, and everything else."""
    pred = [r for r in rows if r["kind"] == "predicted"]
    return {"predicted": len(pred), "predicted_match": sum(r["verdict"] == "match" for r in pred),
            "predicted_mismatch": sum(r["verdict"] == "mismatch" for r in pred),
            "predicted_qualitative": sum(r["verdict"] == "qualitative" for r in pred),
            "fitted": len(rows) - len(pred)}


# The PneuNet's mechanical lag (docs/physics.md, "Actuator dynamics"): assumed, the published
# text gives no figure. The pneunet profiles keep 0: their paper protocols read after 4 s and
# a 0.05 s lag moves those readings by under 0.001 kPa; the studies that read within the first
# second (the timing section, `python -m lab bench speed-accuracy`) add it.
PNEUNET_RESPONSE_S = 0.05


def profile(name: str) -> Profile:
    return load_profile(PROFILES / f"{name}.yaml")


def run_on(prof: Profile, body, seed: int = 1):
    """``await body(controller)`` on a virtual simulated cell; returns its result."""
    cfg, backend = sim_cell(prof, seed)

    async def main():
        async with Controller(cfg, backend) as ctrl:
            return await body(ctrl)

    return asyncio.run(main())


def fit(runs, feature: str, fit_kind: str = "linear", **meta) -> Calibration:
    x = [r.target for r in runs if feature_value(r.result, feature) is not None]
    y = [feature_value(r.result, feature) for r in runs if feature_value(r.result, feature) is not None]
    defaults = dict(profile="", method="", feature=feature, feature_unit="", scene={}, target="", target_unit="")
    defaults.update(meta)
    return Calibration.fit_points(x, y, fit_kind, date="generated", **defaults)


def errors_on(cal: Calibration, runs, feature: str) -> np.ndarray:
    out = []
    for r in runs:
        y = feature_value(r.result, feature)
        out.append(np.nan if y is None else cal.invert(y).estimate - r.target)
    return np.array(out)


def interval95(err: np.ndarray) -> tuple[float, float]:
    e = err[np.isfinite(err)]
    return float(np.percentile(e, 2.5)), float(np.percentile(e, 97.5))


def r4(x: float) -> float:
    """Four significant digits: what results.json and the text keep."""
    return float(f"{x:.4g}")


def md_table(header: list[str], rows: list[list[Any]]) -> str:
    def cell(v):
        return f"{v:.4g}" if isinstance(v, float) else str(v)

    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def img(name: str, alt: str) -> str:
    return f"![{alt}]({name})"


def out_path(out_dir: str | Path) -> Path:
    p = Path(out_dir)
    p.mkdir(parents=True, exist_ok=True)
    return p
