"""``fluidsense check``: look at a real cell before running it (cli/check/)."""

from __future__ import annotations

import argparse
import sys

from fluidsense.common import stopsignals
from fluidsense.common.exitcodes import EXIT_BAD_INPUT, EXIT_FAULT, EXIT_OK


def register(sub) -> None:
    p = sub.add_parser(
        "check", help="bring-up check of a cell: connect, read, judge; --actuate pulses each valve",
        description="Connect to the cell of a config through its driver (sim, ur, modbus) and report what it finds: "
        "the robot's version and modes (UR dashboard), the valve outputs as the device reports them, the rate the "
        "device really delivers with gaps and lateness, each sensor's signal and pressure through the wiring's "
        "transfer, its noise against the profile's. Read-only: it writes nothing to the device. With --actuate "
        "(asks first unless --yes) it vents, pulses each valve in turn with the regulator at a test pressure and "
        "checks that the pressures answer as the wiring says (swapped outputs, inverted valves, no air, dead "
        "sensors, leaks), and ends in the safe state confirmed by read-back, also on Ctrl-C or an error. Exit 0 "
        "when everything matches, 4 with one line per problem, 3 when a device does not answer, 2 for a bad config.")
    p.add_argument("--config", "-c", required=True, help="cell config")
    p.add_argument("--seconds", type=float, default=3.0, help="how long to sample (default 3 s)")
    p.add_argument("--timeout", type=float, default=10.0, metavar="S", help="each device's answer (default 10 s)")
    p.add_argument("--actuate", action="store_true", help="pulse each valve and check the pressures answer")
    p.add_argument("--yes", "-y", action="store_true", help="with --actuate: do not ask for confirmation")
    p.add_argument("--test-kpa", type=float, help="regulator setpoint during the pulses (default: half the profile's "
                   "p0, at most 20 kPa)")
    p.add_argument("--pulse-s", type=float, default=0.6, help="duration of each step (default 0.6 s)")
    p.add_argument("--zero-kpa", type=float, default=2.0, help="the vented actuator's sensor must read within this "
                   "of 0 kPa gauge (default 2)")
    p.add_argument("--log-level", choices=["DEBUG", "INFO", "WARNING", "ERROR"], default="ERROR")
    p.set_defaults(func=main)


def _positive(name: str, value: float) -> None:
    from fluidsense.common.errors import ConfigError

    if not 0 < value < 3600:
        raise ConfigError(f"{name}: must be in (0, 3600), got {value:g}")


def main(args: argparse.Namespace) -> int:
    from fluidsense.cli.check import CheckOptions, describe_plan, run_check
    from fluidsense.controller.config import load_cell_config

    from ._common import print_signal_stop, setup_logging

    for name in ("seconds", "timeout", "pulse_s", "zero_kpa"):
        _positive(f"--{name.replace('_', '-')}", getattr(args, name))
    cfg = load_cell_config(args.config)
    setup_logging(args.log_level)
    opts = CheckOptions(seconds=args.seconds, timeout_s=args.timeout, actuate=args.actuate, test_kpa=args.test_kpa,
                        pulse_s=args.pulse_s, zero_kpa=args.zero_kpa)
    if args.actuate and not args.yes:
        print(describe_plan(cfg, opts))
        if not sys.stdin.isatty():
            print("fluidsense: error: --actuate moves the valves: confirm on a terminal, or pass --yes",
                  file=sys.stderr)
            return EXIT_BAD_INPUT
        if input("Type yes to go on: ").strip().lower() != "yes":
            print("not confirmed: nothing was moved", file=sys.stderr)
            return EXIT_BAD_INPUT
    backends = []  # the one check connected: where a stop left its valves
    try:
        problems = stopsignals.run(run_check(cfg, args.config, opts, lambda line: print(line, flush=True),
                                             on_backend=backends.append))
    except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM, SIGHUP: after the check's own way back to safe
        sig = stopsignals.interruption(exc)
        if not args.actuate:
            print(f"fluidsense: check stopped by {sig.name}; read-only: nothing was written", file=sys.stderr)
            return sig.exit_code
        return print_signal_stop(sig, "check --actuate", backends[0].valves if backends else None)
    return EXIT_FAULT if problems else EXIT_OK
