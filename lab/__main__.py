"""``python -m lab``: the studies' command line (bench, report, simserial)."""

from __future__ import annotations

import argparse
import sys

from fluidsense.cli import exit_codes_text, run_parsed

from lab.subcommands import bench, report, simserial


def build_parser(argv: list[str]) -> argparse.ArgumentParser:
    """The benches are only looked up when ``argv`` asks for one (loading them all costs most
    of a second)."""
    parser = argparse.ArgumentParser(
        prog="python -m lab", description="The studies of fluidsense: benchmarks that print figures, the "
        "reproduction report, the serial firmware's host board on a pty. Run from a checkout.",
        epilog=exit_codes_text(), formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    bench.register(sub, full=argv[:1] == ["bench"])
    report.register(sub)
    simserial.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    return run_parsed(build_parser(argv).parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
