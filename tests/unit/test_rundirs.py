"""The private folders of a daemon's ipc endpoints (common/rundirs.py): a killed daemon's
are removed by the next start, nothing else is."""

from __future__ import annotations

import os
from pathlib import Path

from fluidsense.common import rundirs

PREFIX = "fluidsense-test-"


def _gone_pid() -> int:
    """A pid no process can have: above the kernel's largest."""
    return int(Path("/proc/sys/kernel/pid_max").read_text()) + 1


def test_only_our_users_folders_of_gone_processes_are_removed(tmp_path):
    gone, alive = _gone_pid(), os.getpid()
    stale = tmp_path / f"{PREFIX}{gone}-abc"
    stale.mkdir()
    (stale / "data").write_text("")  # where the endpoint's socket file was
    (stale / "sub").mkdir()
    live = tmp_path / f"{PREFIX}{alive}-def"
    live.mkdir()
    no_pid = tmp_path / f"{PREFIX}x{gone}-ghi"
    no_pid.mkdir()
    a_file = tmp_path / f"{PREFIX}{gone}-file"
    a_file.write_text("")
    target = tmp_path / "elsewhere"
    target.mkdir()
    (target / "keep").write_text("")
    link = tmp_path / f"{PREFIX}{gone}-link"
    link.symlink_to(target)
    other_kind = tmp_path / f"fluidsense-other-{gone}-jkl"
    other_kind.mkdir()

    assert rundirs.sweep_stale(PREFIX, tmp_path) == [stale]
    assert not stale.exists()
    assert live.is_dir() and no_pid.is_dir() and a_file.is_file() and link.is_symlink() and other_kind.is_dir()
    assert (target / "keep").exists()  # a link is not followed


def test_a_new_folder_is_private_named_for_its_process_and_sweeps_first(tmp_path, monkeypatch):
    monkeypatch.setattr(rundirs.tempfile, "tempdir", str(tmp_path))
    stale = tmp_path / f"{PREFIX}{_gone_pid()}-abc"
    stale.mkdir()
    made = rundirs.private_dir(PREFIX)
    assert not stale.exists()
    assert made.parent == tmp_path and made.name.startswith(f"{PREFIX}{os.getpid()}-")
    assert made.stat().st_mode & 0o777 == 0o700  # only our user reaches the endpoints inside
