"""Opening files that come from outside: configs, profiles, task files, calibrations,
recordings.

Every one of them is untrusted input. A path may name a FIFO (opening it for reading
blocks until a writer appears), a device (``/dev/zero`` reads for ever), a directory or a
socket, or a file far larger than its kind can be. Here a path is checked with
``os.stat`` before it is opened, opened with ``O_NONBLOCK`` (so a FIFO swapped in between
the check and the open cannot block) and checked again on the open descriptor, and a
whole-file read stops one byte past the cap of its kind. Every refusal is one line,
``FILE: cannot read: reason``, raised as the caller's error class.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import BinaryIO

from fluidsense.common.errors import ConfigError, FluidsenseError

MB = 2**20
# A shipped config or profile is a few KB; 1 MB leaves room for long comments and wiring
# tables while keeping a YAML parse well under a second.
YAML_MAX_BYTES = 1 * MB

_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket"),
          (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"))


def describe(mode: int) -> str:
    for test, name in _KINDS:
        if test(mode):
            return name
    return "not a regular file"


def check_name(path: str | Path, error: type[FluidsenseError] = ConfigError) -> Path:
    """A path without NUL bytes (the OS cannot open one; Python raises ValueError)."""
    text = os.fspath(path)
    if "\0" in text:
        shown = text.replace("\0", "\\0")
        raise error(f"{shown}: cannot read: the file name contains a NUL byte")
    return Path(text)


def open_regular(path: str | Path, error: type[FluidsenseError] = ConfigError) -> BinaryIO:
    """Open a regular file for binary reading without ever blocking on it."""
    path = check_name(path, error)
    try:
        st = os.stat(path)
    except OSError as exc:
        raise error(f"{path}: cannot read: {exc.strerror or exc}") from exc
    if not stat.S_ISREG(st.st_mode):
        raise error(f"{path}: cannot read: not a regular file ({describe(st.st_mode)})")
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | getattr(os, "O_NOCTTY", 0))
    except OSError as exc:
        raise error(f"{path}: cannot read: {exc.strerror or exc}") from exc
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):  # replaced between the stat and the open
            raise error(f"{path}: cannot read: not a regular file ({describe(st.st_mode)})")
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def size_text(n: int) -> str:
    return f"{n / MB:.3g} MB" if n >= MB else f"{n} bytes"


def read_bounded(path: str | Path, max_bytes: int, what: str,
                 error: type[FluidsenseError] = ConfigError) -> bytes:
    """The whole of a regular file of at most ``max_bytes`` (``what`` names the kind of
    file in the refusal: "a config file")."""
    with open_regular(path, error) as f:
        size = os.fstat(f.fileno()).st_size
        too_big = error(f"{path}: cannot read: larger than the {size_text(max_bytes)} {what} may have")
        if size > max_bytes:
            raise too_big
        try:
            data = f.read(max_bytes + 1)  # the file may have grown since the fstat
        except OSError as exc:
            raise error(f"{path}: cannot read: {exc.strerror or exc}") from exc
    if len(data) > max_bytes:
        raise too_big
    return data


def decode_utf8(data: bytes, path: str | Path, error: type[FluidsenseError] = ConfigError) -> str:
    """UTF-8 text (a leading byte-order mark is dropped); a bad byte is reported with its
    line and column."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        column = exc.start - (data.rfind(b"\n", 0, exc.start) + 1) + 1
        raise error(f"{path}:{line}:{column}: cannot read: not UTF-8 text (byte 0x{data[exc.start]:02x})") from exc


def one_line(text: str) -> str:
    """A reason as one line of plain text: a key or value quoted from the file may hold
    line breaks (``str.splitlines`` knows eight) or terminal control sequences."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in text)


def nested_within(data: object, depth: int) -> bool:
    """Whether parsed JSON has no more than ``depth`` levels of containers (checked
    without recursion, so any depth is safe to ask about)."""
    todo = [(data, 1)]
    while todo:
        node, level = todo.pop()
        if isinstance(node, (dict, list)):
            if level > depth:
                return False
            todo.extend((child, level + 1) for child in (node.values() if isinstance(node, dict) else node))
    return True


__all__ = ["MB", "YAML_MAX_BYTES", "check_name", "decode_utf8", "describe", "nested_within", "one_line", "open_regular",
           "read_bounded"]
