"""The ``fluidsense`` command line. Subcommands live in ``fluidsense/commands/``."""

from __future__ import annotations

import argparse
import sys

from drivers.errors import CommandError, ConfigError, FluidsenseError, RecordingError, SafetyError

from .commands import MODULES

# Exit codes, the same for every command (docs/cli.md "Exit codes").
EXIT_OK = 0  # success, or a clean stop (Ctrl-C aside, SIGTERM, shutdown)
EXIT_FAILURE = 1  # the daemon stopped on a failure inside it (it vented first); systemd restarts it
EXIT_BAD_INPUT = 2  # a bad config/profile/task/calibration/recording file, argument or refused command: nothing started
EXIT_TIMEOUT = 3  # no reply from the daemon or a device in time
EXIT_FAULT = 4  # a fault ended the job (task, calibrate, sense)
EXIT_INTERRUPTED = 130  # Ctrl-C (128 + SIGINT)

EXIT_CODES = {
    EXIT_OK: "success, or a clean stop (SIGTERM, shutdown command)",
    EXIT_FAILURE: "the daemon stopped on a failure inside it, after venting (systemd restarts it)",
    EXIT_BAD_INPUT: "bad input: a config, profile, task, calibration or recording file, an argument or a "
                    "refused command; nothing was started",
    EXIT_TIMEOUT: "timeout: no reply from the daemon or a device",
    EXIT_FAULT: "a fault ended the job (task, calibrate, sense)",
    EXIT_INTERRUPTED: "interrupted (Ctrl-C)",
}

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
    args = build_parser().parse_args(argv)  # a bad argument: argparse exits with 2
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


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
