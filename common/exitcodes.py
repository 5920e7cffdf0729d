"""Exit codes, the same for every command (docs/cli.md "Exit codes")."""

from __future__ import annotations

EXIT_OK = 0  # success, or the daemon's clean stop (a stop signal, a shutdown command)
EXIT_FAILURE = 1  # the daemon stopped on a failure inside it (it vented first); systemd restarts it
EXIT_BAD_INPUT = 2  # a bad config/profile/task/calibration/recording file, argument or refused command: nothing started
EXIT_TIMEOUT = 3  # no reply from the daemon or a device in time
EXIT_FAULT = 4  # a fault ended the job (task, calibrate, sense)
# A job (calibrate, sense, task run, check --actuate, demo) stopped by a signal, after it
# vented: 128 + the signal's number, as a shell reports it (common/stopsignals.py)
EXIT_HANGUP = 129  # SIGHUP: the terminal or SSH session closed
EXIT_INTERRUPTED = 130  # Ctrl-C (SIGINT)
EXIT_TERMINATED = 143  # SIGTERM: systemd, docker stop, timeout, a CI runner

EXIT_CODES = {
    EXIT_OK: "success, or the daemon's clean stop (SIGTERM, SIGINT, SIGHUP, shutdown command)",
    EXIT_FAILURE: "the daemon stopped on a failure inside it, after venting (systemd restarts it)",
    EXIT_BAD_INPUT: "bad input: a config, profile, task, calibration or recording file, an argument or a "
                    "refused command; nothing was started",
    EXIT_TIMEOUT: "timeout: no reply from the daemon or a device",
    EXIT_FAULT: "a fault ended the job (task, calibrate, sense)",
    EXIT_HANGUP: "a job stopped by SIGHUP (terminal closed), after venting",
    EXIT_INTERRUPTED: "interrupted (Ctrl-C), after venting",
    EXIT_TERMINATED: "a job stopped by SIGTERM (systemd, docker stop, timeout), after venting",
}

