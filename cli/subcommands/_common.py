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


def vent_words(valves, since: float) -> str:
    """Where the valves were left after a job stopped, as the device last reported them
    (``valves``: the backend's valve bank, None when the job never connected); a report
    older than ``since`` (time.monotonic() of the stop) does not count as confirmation."""
    if valves is None:  # the controller's start undoes itself: what was set up is vented and closed
        return "it stopped while connecting: whatever was set up was put in its safe state and closed"
    if not valves.reports_outputs:
        return "every valve commanded to its safe position (this device cannot report its outputs)"
    if valves.reported is None or valves.reported_at is None or valves.reported_at < since \
            or valves.report_error is not None:
        why = f" ({valves.report_error})" if valves.report_error else ""
        return (f"the safe state was commanded but the device did not confirm it{why}: check that the gripper "
                "is vented")
    if valves.reports_safe(valves.reported):
        return "vented: every valve at its safe position, confirmed by read-back"
    return (f"the device reports {valves.reported} after the safe state was commanded: vent the gripper by hand "
            "and look for what holds the outputs")


def print_signal_stop(sig, job: str, valves, after: str = "") -> int:
    """A job a stop signal (Ctrl-C, SIGTERM, SIGHUP) ended, once it has unwound: what it
    was, where the valves were left, ``after`` (what was kept, how to go on) on stderr; its
    exit code (common/stopsignals.py)."""
    print(f"fluidsense: {job} stopped by {sig.name}; {vent_words(valves, sig.at)}" + (f"; {after}" if after else ""),
          file=sys.stderr, flush=True)
    return sig.exit_code


class Progress:
    """Progress of a long job on stderr: a bar on a terminal, else a line at each stage and
    every tenth of the way (a log, a CI job). Called as ``progress(stage, steps_done)``."""

    def __init__(self, total: int, desc: str, stream=None):
        self.total, self.desc, self.stream = max(1, total), desc, stream or sys.stderr
        self.done, self.stage, self.bar, self._said = 0, "", None, -1

    def __enter__(self) -> Progress:
        if self.stream.isatty():
            from tqdm import tqdm

            self.bar = tqdm(total=self.total, desc=self.desc, unit="step", file=self.stream)
        return self

    def __exit__(self, *exc) -> None:
        if self.bar is not None:
            self.bar.close()
        elif exc[0] is None and self._said < 10:
            self._line()

    def __call__(self, stage: str, n: int = 1) -> None:
        self.done += n
        if self.bar is not None:
            if stage != self.stage:
                self.bar.set_description(f"{self.desc}: {stage}")
            self.bar.update(n)
        elif stage != self.stage or 10 * self.done // self.total > self._said:
            self._said = 10 * self.done // self.total
            self.stage = stage
            self._line()
        self.stage = stage

    def _line(self) -> None:
        print(f"{self.desc}: {self.stage} {self.done}/{self.total} ({100 * self.done / self.total:.0f} %)",
              file=self.stream, flush=True)
