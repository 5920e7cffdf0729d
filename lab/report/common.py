"""Shared pieces of the report sections: running a profile, fitting, formatting."""

from __future__ import annotations

import asyncio
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from fluidsense.cli.options import PROFILES
from fluidsense.controller.config import Profile, load_profile
from fluidsense.controller.sensing.calibration import Calibration, feature_value
from fluidsense.controller.service import open_cell
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
            kind: str, tolerance: str = "", figures: tuple[str, ...] = (), parameter: str = "",
            set_from: tuple[str, ...] = ()) -> None:
        """One ledger row. ``paper``: what the published text says, with its uncertainty;
        ``source``: where (figure/table/section); ``figures``: the published numbers this row
        compares with, each "<number> <unit>" as written in ``paper`` (none: the text states
        no number here, and the row is qualitative whatever ``match`` says: ``match`` then
        tells whether the stated claim holds in ours).

        ``kind``: ``predicted`` (nothing in the model was set from these figures),
        ``fitted`` (``parameter`` was set from ``set_from``, published numbers "<number>
        <unit>"; such a row agrees by construction and is never counted as a prediction, and
        no predicted row may compare with a figure a fitted row was set from or compares
        with: tests/unit/test_report.py checks it over the ledger), or ``self-check`` (our code
        against our own analytic solution: no paper number, kept apart from the ledger).
        ``tolerance``: what "match" means: the paper's own spread, or a stated sampling or
        reading error."""
        if kind not in ("predicted", "fitted", "self-check"):
            raise ValueError(f"row kind must be 'predicted', 'fitted' or 'self-check', got {kind!r}: {quantity}")
        if kind == "fitted" and not (parameter and set_from):
            raise ValueError(f"a fitted row names its parameter and the figure it was set from: {quantity}")
        if kind != "fitted" and (parameter or set_from):
            raise ValueError(f"only a fitted row has a parameter: {quantity}")
        for f in figures:
            if f.split()[0] not in paper:
                raise ValueError(f"figure {f!r} is not in the row's published text {paper!r}: {quantity}")
        numeric = bool(figures) and match is not None
        if numeric and not match and not why:
            raise ValueError(f"mismatch without a reason: {quantity}")
        if numeric and not tolerance:
            raise ValueError(f"a numeric verdict states its tolerance: {quantity}")
        verdict = ("match" if match else "mismatch") if numeric else "qualitative"
        holds = None if numeric or match is None else bool(match)
        self.rows.append({"quantity": quantity, "paper": paper, "ours": ours, "verdict": verdict, "holds": holds,
                          "kind": kind, "parameter": parameter, "set_from": list(set_from),
                          "figures": list(figures), "tolerance": tolerance, "why": why, "source": source})


def ledger_counts(rows: list[dict[str, Any]]) -> dict[str, int]:
    """The summary line: predicted rows split into numeric agreement, numeric disagreement and
    qualitative; fitted rows and self-checks apart."""
    pred = [r for r in rows if r["kind"] == "predicted"]
    return {"predicted": len(pred), "numeric_agree": sum(r["verdict"] == "match" for r in pred),
            "numeric_disagree": sum(r["verdict"] == "mismatch" for r in pred),
            "qualitative": sum(r["verdict"] == "qualitative" for r in pred),
            "fitted": sum(r["kind"] == "fitted" for r in rows),
            "self_checks": sum(r["kind"] == "self-check" for r in rows)}


_FIGURE = re.compile(r"^([-+]?\d+(?:\.\d+)?)\s*(\S+)")


def _figure(text: str) -> tuple[float, str] | None:
    """"0.04 kPa/mm" -> (0.04, "kPa/mm"); a description ("Fig. 1f: ...") -> None."""
    m = _FIGURE.match(text.strip())
    return (abs(float(m.group(1))), m.group(2)) if m else None


def ledger_problems(rows: list[dict[str, Any]]) -> list[str]:
    """What would let the ledger flatter: a numeric verdict without a published number or a
    tolerance, a fitted row that does not name its parameter and figure, or a predicted row
    that compares with a figure some fitted row was set from or agrees with by construction
    (numbers compared with their unit, sign dropped)."""
    out = []
    fitted = {}
    for r in rows:
        if r["kind"] == "fitted":
            if not (r["parameter"] and r["set_from"]):
                out.append(f"fitted row without its parameter and figure: {r['quantity']}")
            for f in r["set_from"] + r["figures"]:
                if _figure(f):
                    fitted[_figure(f)] = r["quantity"]
    for r in rows:
        if r["verdict"] in ("match", "mismatch") and not (r["figures"] and r["tolerance"]):
            out.append(f"numeric verdict without a published number or a tolerance: {r['quantity']}")
        if r["kind"] == "self-check" and r["figures"]:
            out.append(f"a self-check compares with no paper number: {r['quantity']}")
        if r["kind"] == "predicted":
            for f in r["figures"]:
                if _figure(f) in fitted:
                    out.append(f"predicted row {r['quantity']!r} compares with {f}, which "
                               f"{fitted[_figure(f)]!r} is fitted to")
    return out


# The PneuNet's mechanical lag (docs/physics.md, "Actuator dynamics"): assumed, the published
# text gives no figure. The pneunet profiles keep 0: their paper protocols read after 4 s and
# a 0.05 s lag moves those readings by under 0.001 kPa; the studies that read within the first
# second (the timing section, `python -m lab bench speed-accuracy`) add it.
PNEUNET_RESPONSE_S = 0.05


def profile(name: str) -> Profile:
    return load_profile(PROFILES / f"{name}.yaml")


def run_on(prof: Profile, body, seed: int = 1):
    """``await body(port)`` on a virtual simulated cell, ``port`` its controller's task port
    (controller/ports.py); returns its result."""
    cfg, backend = sim_cell(prof, seed)

    async def main():
        async with open_cell(cfg, backend) as port:
            return await body(port)

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
