"""Helpers shared by the subcommands."""

from __future__ import annotations

import logging
import sys


def setup_logging(level: str, quiet: bool = False) -> None:
    logging.basicConfig(level=logging.WARNING if quiet else getattr(logging, level),
                        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s", stream=sys.stderr)


def print_stopped(exc, as_json: bool) -> None:
    """A job that a fault (or a failure) stopped: what stopped it on stderr, and what it had
    done on stdout (JSON with ``--json``, so that scripts keep the partial result)."""
    import json

    print(f"fluidsense: {exc}", file=sys.stderr)
    if as_json:
        print(json.dumps(exc.partial, indent=2, default=float))
        return
    for key, value in exc.partial.items():
        if key == "steps":
            print(f"steps done ({len(value)}):")
            for step in value:
                print("  " + ", ".join(f"{k}={v}" for k, v in step.items()))
        else:
            print(f"{key}: {value}")
