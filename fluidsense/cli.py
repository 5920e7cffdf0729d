"""The ``fluidsense`` command line. Subcommands live in ``fluidsense/commands/``."""

from __future__ import annotations

import argparse
import sys

from drivers.errors import FluidsenseError

from .commands import MODULES


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fluidsense",
        description="Closed-loop controller for soft pneumatic grippers with retrofit fluidic sensing.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in MODULES:
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except FluidsenseError as exc:
        print(f"fluidsense: error: {exc}", file=sys.stderr)
        return 2
    except TimeoutError as exc:
        print(f"fluidsense: error: {exc}", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
