"""``fluidsense replay FILE``: the feature pipeline run again on a recording."""

from __future__ import annotations

import argparse
import asyncio
import json

from ._common import setup_logging

COLUMNS = (("p_eq_kpa", "P_eq kPa", ".3f"), ("dp_eq_kpa", "dP kPa", ".3f"), ("t_c_slope_s", "t_c slope s", ".3f"))


def register(sub) -> None:
    p = sub.add_parser("replay", help="recompute every cycle of a recording and compare with the live results",
                       description="Read a recording made by `fluidsense run` (up to its last complete record if "
                       "the daemon was killed), recompute each cycle's features from the recorded samples and "
                       "transitions with the recorded config, and print them next to the live results. Exit 0 "
                       "if every complete cycle is identical, 1 if one differs, 2 for a bad file.")
    p.add_argument("file", help="the recording (.mcap)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=main)


def _cell(result: dict | None, key: str, fmt: str) -> str:
    value = None if result is None else result.get(key)
    return "-" if value is None else format(value, fmt)


def print_report(report) -> None:
    r = report
    state = "closed by the daemon" if r.closed else (
        f"not closed (daemon killed?): read up to its last complete record, {r.dropped_bytes} bytes after it ignored")
    span = "no samples" if r.t_first_s is None else f"t = {r.t_first_s:.3f} .. {r.t_last_s:.3f} s"
    print(f"{r.file}: {state}")
    print(f"{r.samples} samples in {r.blocks} blocks, {span}, {len(r.cycles)} cycles")
    head = f"{'cycle':>5}  {'label':<12} {'status':<10} {'agree':<5}"
    for _, title, _ in COLUMNS:
        head += f"  {title + ' live'} {title + ' replay'}"
    print(head)
    for c in r.cycles:
        agree = {True: "yes", False: "NO", None: "-"}[c.agree]
        line = f"{c.cycle_id:>5}  {str(c.label or '-'):<12} {'complete' if c.complete else 'incomplete':<10} {agree:<5}"
        for key, title, fmt in COLUMNS:
            line += f"  {_cell(c.live, key, fmt):>{len(title) + 5}} {_cell(c.replay, key, fmt):>{len(title) + 7}}"
        print(line)
        if c.differences:
            print(f"       differs in: {', '.join(c.differences)}")
        if c.replay.get("aborted"):
            print(f"       aborted: {c.replay['aborted']}")
    bad = [c.cycle_id for c in r.cycles if c.agree is False]
    print("every complete cycle identical to its live result" if not bad else f"cycles {bad} differ")


def main(args: argparse.Namespace) -> int:
    from fluidsense.controller.cycles.reanalysis import replay_file

    setup_logging("WARNING")
    report = asyncio.run(replay_file(args.file))
    if args.json:
        print(json.dumps(report.to_dict(), indent=2))
    else:
        print_report(report)
    return 0 if report.agree else 1
