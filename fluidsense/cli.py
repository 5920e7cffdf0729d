"""The ``fluidsense`` command line. Subcommands live in ``fluidsense/commands/``."""

from __future__ import annotations

import argparse
import os
import sys

from common.errors import CommandError, ConfigError, FluidsenseError, RecordingError, SafetyError

from .commands import MODULES, bench
from .exitcodes import EXIT_BAD_INPUT, EXIT_CODES, EXIT_FAILURE, EXIT_FAULT, EXIT_INTERRUPTED, EXIT_OK, EXIT_TIMEOUT  # noqa: F401

BAD_INPUT = (ConfigError, RecordingError, CommandError, SafetyError)


def exit_codes_text() -> str:
    return "exit codes:\n" + "\n".join(f"  {code:>3}  {meaning}" for code, meaning in EXIT_CODES.items())


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """``argv``: the command line to be parsed; the benches are only looked up when it asks
    for one (loading them all costs most of a second)."""
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(
        prog="fluidsense",
        description="Closed-loop controller for soft pneumatic grippers with retrofit fluidic sensing.",
        epilog=exit_codes_text(), formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in MODULES:
        if module is bench:
            module.register(sub, full=argv[:1] == ["bench"])
        else:
            module.register(sub)
    return parser


def report(exc: BaseException) -> None:
    """One line per problem on stderr, each prefixed (a config error lists every bad field)."""
    for line in str(exc).splitlines() or [type(exc).__name__]:
        print(f"fluidsense: error: {line}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    args = build_parser(argv).parse_args(argv)  # a bad argument: argparse exits with 2
    try:
        return args.func(args)
    except BAD_INPUT as exc:
        report(exc)
        return EXIT_BAD_INPUT
    except TimeoutError as exc:  # DeviceTimeoutError included
        report(exc)
        return EXIT_TIMEOUT
    except FluidsenseError as exc:  # the lead maps faults and failures to EXIT_FAULT / EXIT_FAILURE
        report(exc)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # the reader went away (`fluidsense cmd status | head`): stop quietly
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # the interpreter's own flush at exit must not fail again
        return EXIT_OK


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
