"""CURVE key files for the command socket: written private, read only when private.

The files are ZeroMQ certificates as pyzmq's ``zmq.auth`` reads and writes them; only the
file handling is ours, because ``zmq.auth.create_certificates`` writes secret keys with
the process's umask (0644 usually) and ``load_certificate`` reads whatever it is given.
"""

from __future__ import annotations

import datetime
import os
import stat
from pathlib import Path

from fluidsense.common.errors import ConfigError

MAX_KEY_FILE_BYTES = 64 * 1024  # a certificate is a few hundred bytes
ALLOW_ANY = "*"  # pyzmq's "any client key" location


def write_key_file(path: str | Path, public: bytes, secret: bytes | None = None) -> None:
    """Write a certificate; with ``secret`` the file is created 0600 whatever the umask,
    and an existing file is never overwritten (it could have been readable)."""
    kind = "Secret" if secret is not None else "Public"
    lines = [f"#   ****  Generated on {datetime.datetime.now()} by fluidsense keys  ****",
             f"#   ZeroMQ CURVE {kind} Certificate", "", "metadata", "curve",
             f'    public-key = "{public.decode()}"']
    if secret is not None:
        lines.insert(2, "#   DO NOT PROVIDE THIS FILE TO OTHER USERS nor change its permissions.")
        lines.append(f'    secret-key = "{secret.decode()}"')
    mode = 0o600 if secret is not None else 0o644
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    try:
        os.fchmod(fd, mode)  # the umask may have taken bits away (or, for 0644, left too few)
        os.write(fd, ("\n".join(lines) + "\n").encode())
    finally:
        os.close(fd)


def _read_key_file(path: Path) -> tuple[bytes | None, bytes | None]:
    """(public, secret) of a certificate; ConfigError naming the file when it is not one."""
    try:
        st = path.stat()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    if not stat.S_ISREG(st.st_mode):
        raise ConfigError(f"{path}: not a regular file")
    if st.st_size > MAX_KEY_FILE_BYTES:
        raise ConfigError(f"{path}: {st.st_size} bytes is too large for a key file")
    try:
        text = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    keys: dict[bytes, bytes] = {}
    for line in text.splitlines():
        name, sep, value = line.strip().partition(b"=")
        if sep and name.strip() in (b"public-key", b"secret-key"):
            keys[name.strip()] = value.strip(b" \t'\"")
    return keys.get(b"public-key"), keys.get(b"secret-key")


def check_private(path: str | Path) -> None:
    """A secret key file readable by group or others is refused: whoever could read it can
    pose as its owner."""
    path = Path(path)
    try:
        mode = stat.S_IMODE(path.stat().st_mode)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    if mode & 0o077:
        raise ConfigError(f"{path}: secret key file is readable by group or others (mode {mode:04o}); "
                          f"chmod 600 it")


def read_secret_key(path: str | Path) -> tuple[bytes, bytes]:
    """(public, secret) from a secret key file that only its owner can read."""
    path = Path(path)
    check_private(path)
    public, secret = _read_key_file(path)
    if public is None or secret is None:
        raise ConfigError(f"{path}: holds no {'public' if public is None else 'secret'} key "
                          "(fluidsense keys writes one)")
    return public, secret


def count_public_keys(directory: str | Path) -> int:
    """How many client public keys (``*.key``, as pyzmq's authenticator reads them) a
    directory holds; ConfigError when it is not a readable directory."""
    directory = Path(directory)
    if not directory.is_dir():
        raise ConfigError(f"{directory}: no such directory")
    try:
        files = sorted(directory.glob("*.key"))
    except OSError as exc:
        raise ConfigError(f"{directory}: cannot read: {exc.strerror or exc}") from exc
    return sum(1 for f in files if _read_key_file(f)[0] is not None)
