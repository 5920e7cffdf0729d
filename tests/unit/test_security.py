"""Bad input and exposure, in this process: the depth check on hostile command messages,
and the CURVE keys `fluidsense keys` writes. (The fuzz and the hostile messages against a
real daemon, and CURVE on its command socket: tests/system/test_security.py.)"""

from __future__ import annotations

import json
import os
import stat

import pytest
from fluidsense.controller.requests.server import too_deep
from support.cli import Ran, run_cli
from support.harness import REPO


@pytest.mark.parametrize("raw, deep", [
    (b"[" * 33 + b"]" * 33, True),
    (b"[" * 32 + b"]" * 32, False),
    (b'{"a": [[{"b": [1]}]]}' * 40, False),  # many brackets, shallow
    (json.dumps({"s": "[" * 100}).encode(), False),
    (json.dumps({"s": '\\"' + "[" * 100}).encode(), False),  # an escaped quote does not end the string
    (b'["\\\\"' + b", [" * 40 + b"]" * 40 + b"]", True),  # an escaped backslash does
])
def test_depth_is_counted_outside_strings(raw, deep):
    assert too_deep(raw) is deep


# ---------------------------------------------------------------- CURVE keys
def _keys(capsys, path, umask: int | None = None, client: str = "client") -> Ran:
    """``fluidsense keys`` in this process under ``umask``, set for the call and put back."""
    old = os.umask(umask) if umask is not None else None
    try:
        return run_cli(capsys, "keys", path, "--client", client, cwd=REPO)
    finally:
        if old is not None:
            os.umask(old)


def _mode(path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


@pytest.mark.parametrize("umask", [0o000, 0o022, 0o077])
def test_keys_writes_secret_keys_0600_whatever_the_umask_and_never_overwrites(tmp_path, umask, capsys):
    out = _keys(capsys, tmp_path / "k", umask)
    assert out.returncode == 0, out.stderr
    k = tmp_path / "k"
    assert _mode(k / "server.key_secret") == 0o600 and _mode(k / "client.key_secret") == 0o600
    assert _mode(k / "server.key") == 0o644 and _mode(k / "clients" / "client.key") == 0o644
    server = (k / "server.key_secret").read_bytes()
    again = _keys(capsys, tmp_path / "k")
    assert again.returncode == 2 and "client.key: exists; keys are never overwritten" in again.stderr
    # another client for the same server: the server's keys stay as they were
    assert _keys(capsys, tmp_path / "k", umask, client="other").returncode == 0
    assert (k / "server.key_secret").read_bytes() == server and _mode(k / "other.key_secret") == 0o600
