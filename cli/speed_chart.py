"""The speed-accuracy chart of one profile and scene as a picture (``fluidsense chart``):
every method's 95 % error against decision time above, its decided fraction below, the
floor on both. The paper's chart (docs/speed-accuracy, lab/bench/_speed_chart.py) draws
its panels with the same lines."""

from __future__ import annotations

from pathlib import Path
from typing import Any

COLOURS = ("C0", "C1", "C2", "C3", "C4")  # one per method, in METHODS' order
FULL = 0.995  # a point decided on (nearly) every cycle is drawn filled


def pyplot():
    """matplotlib's pyplot without a screen, or a CommandError saying how to install it."""
    from fluidsense.common.errors import CommandError

    try:
        import matplotlib
    except ImportError:
        raise CommandError("the chart needs matplotlib, which is not installed: pip install 'matplotlib>=3.8' "
                           "(a dependency of fluidsense; an install with --no-deps leaves it out)") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def method_line(a, rows, colour: str, label: str, top: float) -> None:
    """Decided points filled, partially decided hollow (fraction under 99.5 %), undecided as
    a cross near ``top``: a method that says "not yet" is not a method that is wrong.
    ``rows``: one method's, with ``decision_time_s``, ``decided_fraction`` and the error
    under ``err95`` or ``err95_mm``."""
    def err(r):
        return r["err95"] if "err95" in r else r["err95_mm"]

    decided = [(r["decision_time_s"], err(r)) for r in rows if err(r) is not None and r["decided_fraction"] >= FULL]
    partial = [(r["decision_time_s"], err(r)) for r in rows if err(r) is not None and r["decided_fraction"] < FULL]
    undecided = [r["decision_time_s"] for r in rows if err(r) is None]
    known = sorted(decided + partial)
    if known:
        a.plot(*zip(*known), "-", color=colour, lw=1, label=label)
    if decided:
        a.plot(*zip(*decided), "o", color=colour, ms=2)
    if partial:
        a.plot(*zip(*partial), "o", mfc="white", mec=colour, ms=2.5)
    if undecided:
        a.plot(undecided, [top * 0.85] * len(undecided), "x", color=colour, ms=2.5)


def floor_lines(a, fl: dict[str, float], settled_kpa: float) -> None:
    """The floor: dashed when the farthest target is touched, dotted when settled."""
    a.axvline(fl["contact_s"], color="k", lw=0.8, ls="--", label=f"farthest target touched {fl['contact_s']:.3g} s")
    a.axvline(fl["settled_s"], color="k", lw=0.8, ls=":",
              label=f"settled ({settled_kpa:.2g} kPa) {fl['settled_s']:.3g} s")


def draw(res: dict[str, Any], path: Path, source: str) -> None:
    """``res``: tasks/speed_accuracy.chart's figures; ``source``: where the profile's numbers
    come from, in words (the title's second line)."""
    plt = pyplot()
    rows, fl, unit = res["rows"], res["floor"], res["unit"]
    methods = list(dict.fromkeys(r["method"] for r in rows))
    errs = [r["err95"] for r in rows if r["err95"] is not None]
    span = res["range"][1] - res["range"][0]
    lo = min(errs + [span]) / 2
    top = max(errs + [span]) * 2
    times = res["decision_times_s"]
    fig, (a, b) = plt.subplots(2, 1, sharex=True, figsize=(7.0, 7.0), gridspec_kw={"height_ratios": (2, 1)})
    for colour, m in zip(COLOURS, methods):
        mine = [r for r in rows if r["method"] == m]
        method_line(a, mine, colour, m, top)
        b.plot([r["decision_time_s"] for r in mine], [r["decided_fraction"] for r in mine], "o-", color=colour,
               ms=2, lw=1, label=m)
    ref = res["reference"]
    a.axhline(ref["err95"], color="grey", lw=0.8, ls="-.",
              label=f"window mean at {ref['decision_time_s']:g} s (the reference) {ref['err95']:.3g} {unit}")
    b.axhline(res["decided_at"], color="grey", lw=0.8, ls="-.", label=f"decided: {100 * res['decided_at']:.0f} %")
    for ax in (a, b):
        floor_lines(ax, fl, fl["settled_kpa"])
    a.set(yscale="log", ylim=(lo, top), ylabel=f"95 % absolute error ({unit})")
    b.set(ylim=(-0.02, 1.02), ylabel="fraction of cycles decided", xscale="log",
          xlim=(min(times) / 1.3, max(times) * 1.3), xlabel="decision time after the valve opens (s)")
    a.legend(fontsize=6, loc="upper right")
    b.legend(fontsize=6, loc="lower right")
    lo_t, hi_t = res["range"]
    a.set_title(f"{res['profile']}: {res['target']} {lo_t:g}-{hi_t:g} {unit}, {res['trials']} held-out cycles, "
                f"seed {res['seed']}\n{source}", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)
