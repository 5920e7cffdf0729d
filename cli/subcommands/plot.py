"""``fluidsense plot RECORDING``: recorded cycles as pictures."""

from __future__ import annotations

import argparse

from fluidsense.common.exitcodes import EXIT_BAD_INPUT, EXIT_OK


def register(sub) -> None:
    p = sub.add_parser("plot", help="draw the cycles of a recording (PNG)",
                       description="Pressure against time since the valve opened, per recorded cycle, with the "
                       "free-air reference, the measurement windows, the contact time, P_eq and the result. "
                       "One cycle with --cycle, else every cycle in a grid.")
    p.add_argument("file", help="the recording (.mcap)")
    p.add_argument("--cycle", type=int, help="only this cycle id")
    p.add_argument("--channel", default="p_act", help="the pressure channel to draw (default p_act)")
    p.add_argument("--out", "-o", required=True, help="the picture to write (.png, .svg, .pdf)")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    import sys

    from ..plot import plot_cycles, read_cycles

    plots = read_cycles(args.file, args.channel)
    if args.cycle is not None:
        plots = [p for p in plots if p.cycle_id == args.cycle]
    if not plots:
        which = f"no cycle {args.cycle}" if args.cycle is not None else "no cycle with a result"
        print(f"{args.file}: {which} in this recording", file=sys.stderr)
        return EXIT_BAD_INPUT
    plot_cycles(plots, args.out)
    print(f"{args.out}: {len(plots)} cycle(s)")
    return EXIT_OK
