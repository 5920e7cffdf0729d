"""``fluidsense plot RECORDING``: each recorded cycle as a picture.

Actuator pressure against time since the valve opened (the time base of every feature),
with the free-air reference the cycle was compared with, the measurement windows, the
contact time, P_eq and the result in the title. Everything drawn comes from the file:
the samples as recorded, the live result, the references the file carries or that a
``store_reference`` cycle in it made.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from fluidsense.cli.contact import t_c_text
from fluidsense.common.errors import RecordingError
from fluidsense.common.units import KPA
from fluidsense.controller.cycles.analysis import reference_key
from fluidsense.drivers.recording.reader import RecordingReader
from fluidsense.drivers.recording.schema import REFERENCE


@dataclass
class CyclePlot:
    """One cycle's data as plotted: times (s since the valve opened) and kPa."""

    cycle_id: int
    result: dict[str, Any]
    channel: str
    t_rel_s: np.ndarray
    p_kpa: np.ndarray
    ref_t_rel_s: np.ndarray | None = None
    ref_kpa: np.ndarray | None = None
    windows: list[tuple[str, float, float]] = field(default_factory=list)

    def title(self) -> str:
        r = self.result
        head = f"cycle {self.cycle_id}" + (f" ({r['label']})" if r.get("label") else "") \
            + (" reference" if r.get("is_reference") else "")
        if not r.get("ok"):
            return f"{head}: FAILED ({r.get('aborted')})"
        parts = [f"P_eq {r['p_eq_kpa']:.3f} ± {1.96 * (r.get('p_sd_kpa') or 0):.3f} kPa"]
        if r.get("dp_eq_kpa") is not None:
            parts.append(f"dP {r['dp_eq_kpa']:.3f} kPa")
        if (t_c := t_c_text(r)) is not None:
            parts.append(t_c)
        return f"{head}: " + ", ".join(parts)


def read_cycles(path: str | Path, channel: str = "p_act") -> list[CyclePlot]:
    """Every cycle of the recording that has a live result and a valve opening."""
    blocks_t: list[np.ndarray] = []
    blocks_v: list[np.ndarray] = []
    results: list[dict[str, Any]] = []
    refs: dict[float, tuple[np.ndarray, np.ndarray]] = {}
    channels: tuple[str, ...] | None = None
    with RecordingReader(path) as reader:
        for rec in reader.records():
            if rec.topic == "samples":
                channels = channels or rec.data.channels
                if channel not in rec.data.channels:
                    raise RecordingError(f"{path}: no channel {channel!r} (it has {', '.join(rec.data.channels)})")
                blocks_t.append(rec.data.t)
                blocks_v.append(rec.data.values[:, rec.data.channels.index(channel)])
            elif rec.topic == REFERENCE:
                refs[float(rec.data["key_kpa"])] = (np.asarray(rec.data["t_rel_s"], float),
                                                    np.asarray(rec.data["p_pa"], float))
            elif rec.topic == "cycle":
                results.append(rec.data)
        actuate_s = float(reader.config.get("profile", {}).get("sequence", {}).get("actuate_s", math.inf))
    if not blocks_t:
        raise RecordingError(f"{path}: no samples")
    t, p = np.concatenate(blocks_t), np.concatenate(blocks_v)
    plots = []
    for r in results:
        if r.get("t_open_s") is None:
            continue
        t_open = r["t_open_s"]
        end = r.get("t_end_s") or r.get("t_s") or t[-1]
        sel = (t >= r.get("t_start_s", t_open)) & (t <= end)
        cp = CyclePlot(r["cycle_id"], r, channel, t[sel] - t_open, p[sel] / KPA,
                       windows=[(w["name"], w["start_s"], w["end_s"]) for w in r.get("windows", [])])
        ref = refs.get(reference_key(r["p0_kpa"] * KPA)) if r.get("has_reference") and r.get("p0_kpa") is not None else None
        if ref is not None:  # the reference is offset-corrected: back onto this cycle's offset
            cp.ref_t_rel_s, cp.ref_kpa = ref[0], ref[1] / KPA + (r.get("offset_kpa") or 0.0)
        if r.get("is_reference") and r.get("p0_kpa") is not None:
            # a later cycle at the same P0 is compared with this one (as the controller does:
            # offset-corrected, from the opening for actuate_s)
            opened = (cp.t_rel_s >= 0) & (cp.t_rel_s < actuate_s)
            refs[reference_key(r["p0_kpa"] * KPA)] = (cp.t_rel_s[opened], (cp.p_kpa[opened] - (r.get("offset_kpa") or 0.0)) * KPA)
        plots.append(cp)
    return plots


def draw(ax, cp: CyclePlot) -> None:
    ax.plot(cp.t_rel_s, cp.p_kpa, color="tab:blue", lw=1.0, label=cp.channel)
    if cp.ref_kpa is not None:
        ax.plot(cp.ref_t_rel_s, cp.ref_kpa, color="0.5", lw=1.0, ls="--", label="free-air reference")
    for i, (name, start, end) in enumerate(cp.windows):
        ax.axvspan(start, end, color="tab:orange", alpha=0.2, label="window " + name if i < 3 else None)
    r = cp.result
    ax.axvline(0.0, color="k", lw=0.6, ls=":", label="valve opens")
    if r.get("t_c_threshold_s") is not None:
        ax.axvline(r["t_c_threshold_s"], color="tab:red", lw=1.0, label="contact t_c (threshold)")
    if r.get("p_eq_kpa") is not None and math.isfinite(r["p_eq_kpa"]):
        ax.axhline(r["p_eq_kpa"], color="tab:green", lw=0.8, ls="-.", label="P_eq")
    ax.set_title(cp.title(), fontsize=8)
    ax.set_xlabel("time since the valve opened (s)")
    ax.set_ylabel(f"{cp.channel} (kPa)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6, loc="center right")


def plot_cycles(plots: list[CyclePlot], out: str | Path):
    """One figure (a grid when several cycles), saved to ``out``; returns the figure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(plots)
    cols = min(n, 3)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5.5 * cols, 3.8 * rows), squeeze=False)
    for ax, cp in zip(axes.flat, plots):
        draw(ax, cp)
    for ax in list(axes.flat)[n:]:
        ax.set_visible(False)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    return fig
