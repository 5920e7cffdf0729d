"""The ``fluidsense`` command line. Subcommands live in ``cli/subcommands/``."""

from __future__ import annotations

import argparse
import os
import sys

from fluidsense.cli.subcommands import MODULES
from fluidsense.common.errors import (
    CommandError,
    ConfigError,
    FluidsenseError,
    RecordingError,
    SafetyError,
)
from fluidsense.common.exitcodes import (  # noqa: F401
    EXIT_BAD_INPUT,
    EXIT_CODES,
    EXIT_FAILURE,
    EXIT_FAULT,
    EXIT_HANGUP,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_TERMINATED,
    EXIT_TIMEOUT,
)
from fluidsense.common.stopsignals import interruption

BAD_INPUT = (ConfigError, RecordingError, CommandError, SafetyError)


def exit_codes_text() -> str:
    return "exit codes:\n" + "\n".join(f"  {code:>3}  {meaning}" for code, meaning in EXIT_CODES.items())


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fluidsense",
        description="Closed-loop controller for soft pneumatic grippers with retrofit fluidic sensing.",
        epilog=exit_codes_text(), formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in MODULES:
        module.register(sub)
    return parser


def report(exc: BaseException) -> None:
    """One line per problem on stderr, each prefixed (a config error lists every bad field)."""
    for line in str(exc).splitlines() or [type(exc).__name__]:
        print(f"fluidsense: error: {line}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    return run_parsed(build_parser().parse_args(argv))  # a bad argument: argparse exits with 2


def run_parsed(args: argparse.Namespace) -> int:
    """Run a parsed subcommand; errors become one line on stderr and an exit code."""
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
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM/SIGHUP in a job (common/stopsignals.py): 128 + N
        return interruption(exc).exit_code
    except BrokenPipeError:  # the reader went away (`fluidsense cmd status | head`): stop quietly
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # the interpreter's own flush at exit must not fail again
        return EXIT_OK

