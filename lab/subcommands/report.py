"""``python -m lab report``: regenerate the reproduction report."""

from __future__ import annotations

import argparse
import json
import os
import sys

from fluidsense.cli.subcommands._common import setup_logging


def register(sub) -> None:
    p = sub.add_parser("report", help="regenerate the reproduction report (paper numbers beside ours)",
                       description="Run every experiment of the paper on the simulated cell (virtual time, fixed "
                       "seed) and write README.md, results.json and PNG figures into --out.")
    p.add_argument("--out", default="docs/reproduction", help="output directory (default docs/reproduction)")
    p.add_argument("--jobs", "-j", type=int, default=min(2, os.cpu_count() or 1), help="parallel processes")
    p.add_argument("--only", action="append", help="run only this section (repeatable; writes no README)")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from ..report import generate

    setup_logging("WARNING", quiet=True)

    def progress(title: str) -> None:
        if not args.json:
            print(f"  done: {title}", file=sys.stderr, flush=True)

    res = generate(args.out, jobs=max(1, args.jobs), only=args.only, progress=progress)
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    rows = res["paper_vs_ours"]
    print(f"{len(rows)} comparisons: {sum(r['verdict'] == 'match' for r in rows)} match, "
          f"{sum(r['verdict'] == 'mismatch' for r in rows)} mismatch, "
          f"{sum(r['verdict'] == 'qualitative' for r in rows)} qualitative; {res['wall_s']:.0f} s; written to {args.out}")
    return 0
