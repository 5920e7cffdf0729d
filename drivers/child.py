"""How the daemon's child processes end (the sampler, the ur_rtde worker).

ur_rtde's interfaces wait about 0.5 s each in their destructors for receiving threads that
their ``disconnect()`` already stopped, and a daemon's stop waits for these processes. So a
disconnected interface is kept, never destroyed, and the process ends without the
interpreter's teardown once everything is closed and flushed.
"""

from __future__ import annotations

import logging
import os
import sys
from typing import Any, NoReturn

_KEPT: list[Any] = []


def keep_until_exit(*objects: Any) -> None:
    """Hold ``objects`` (disconnected interfaces) until the process ends."""
    _KEPT.extend(objects)


def exit_now(code: int) -> NoReturn:
    """Flush the logs and the standard streams, then end the process with ``code``."""
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
