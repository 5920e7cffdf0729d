"""Private folders for a daemon's ipc endpoints (the sampler's, the publisher's outlet's,
the live view's).

ZeroMQ's ipc endpoints are socket files; each daemon binds its own in a folder only its
user can enter (mode 0700, from ``tempfile.mkdtemp``), which is what keeps another local
user from connecting to them. Linux's abstract socket names would leave no file behind,
but have no permissions at all, so they are not used. A daemon removes its folders when it
stops; a daemon killed (SIGKILL, the OOM killer, ``systemctl kill -s KILL``) cannot. So
each folder's name carries the pid of the daemon that made it, and making one first
removes the folders of the same kind whose daemon is gone.
"""

from __future__ import annotations

import logging
import os
import shutil
import stat
import tempfile
from pathlib import Path

log = logging.getLogger(__name__)


def private_dir(prefix: str) -> Path:
    """A new folder ``<temp>/<prefix><pid>-XXXXXXXX``, mode 0700, after :func:`sweep_stale`
    of ``prefix``."""
    sweep_stale(prefix)
    return Path(tempfile.mkdtemp(prefix=f"{prefix}{os.getpid()}-"))


def sweep_stale(prefix: str, folder: Path | None = None) -> list[Path]:
    """Remove the folders ``<prefix><pid>-*`` in ``folder`` (the temp folder) that belong to
    our user and whose process is gone; the ones removed. A name without a pid, a file, a
    symbolic link or another user's folder is left as it is."""
    removed = []
    for path in Path(folder or tempfile.gettempdir()).glob(f"{prefix}*-*"):
        try:
            pid = int(path.name.removeprefix(prefix).split("-", 1)[0])
            st = path.lstat()
        except (ValueError, OSError):
            continue
        if st.st_uid != os.getuid() or not stat.S_ISDIR(st.st_mode) or Path(f"/proc/{pid}").exists():
            continue
        shutil.rmtree(path, ignore_errors=True)
        removed.append(path)
    if removed:
        log.info("removed %d folder(s) left by killed daemons: %s", len(removed), ", ".join(p.name for p in removed))
    return removed
