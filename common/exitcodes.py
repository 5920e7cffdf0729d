"""Exit codes, the same for every command (docs/cli.md "Exit codes")."""

from __future__ import annotations

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

