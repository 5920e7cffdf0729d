"""What the sampler process reads: a poller, built inside that process from a spec.

A poller is any class with ``open()``, ``read()`` and ``close()``; deriving from
:class:`Poller` is optional but documents the contract. The daemon never holds a
poller: it sends the spec (``"module:Class"`` and JSON keyword arguments) to the
sampler process, which imports the module and calls ``Class(**kwargs)`` there. So a
poller may hold sockets, file descriptors or C handles that could not cross a process
boundary, and its kwargs must be JSON (no pickle anywhere).

Contract (see docs/sampler.md, "Writing a poller"):

- ``open()`` connects; it may block and may raise (the daemon's ``setup()`` then
  raises ``LinkLostError``). Called once, before the real-time settings apply.
- ``read()`` returns one float per configured channel, in SI units (Pa gauge, m^3/s),
  in the configured channel order. It must return or raise within a bounded time, well
  under one period: slots that pass while it blocks are counted as missed. Raising any
  ``Exception`` marks the slot as failed; reads that keep failing for the sampler's
  ``link_timeout_s`` mean link loss, so ``read()`` should not retry internally.
  Raising :class:`NoNewSample` says the source has nothing new since the last read (a
  box that refreshes slower than the slots come, a late packet): the slot is missed,
  never filled with the old value, and it does not count towards link loss.
- ``read()`` raises ``fluidsense.common.errors.DeviceProtocolError`` (with ``field``)
  when the device said what cannot be true (a NaN, a value no input can measure, a
  timestamp that runs backwards or ahead of the host's clock, a reply of the wrong
  length): the process ends, the daemon makes it one ``driver`` fault naming the field
  and connects again (nothing more that session says is trusted).
- ``read()`` runs with the garbage collector disabled: avoid creating reference cycles
  in it (plain numbers, tuples and lists are fine).
- ``close()`` releases everything; it is called once, also after a failed run.
"""

from __future__ import annotations

import abc
import importlib
import re
from typing import Any

from fluidsense.common.errors import ConfigError


class NoNewSample(Exception):  # noqa: N818 - a slot's outcome, not an error
    """``read()`` found nothing new since the last read: the slot is missed."""


SPEC_PATTERN = r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*:[A-Za-z_][A-Za-z0-9_]*$"


class Poller(abc.ABC):
    """One synchronous read of every channel per call (see the module docstring)."""

    def open(self) -> None:  # noqa: B027 - optional hook
        """Connect to the device. Default: nothing to open."""

    @abc.abstractmethod
    def read(self) -> tuple[float, ...]:
        """One value per channel, SI units."""

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release the device. Default: nothing to close."""


def load_poller(factory: str, kwargs: dict[str, Any] | None = None) -> Poller:
    """Import ``module:Class`` and build it with ``kwargs``. Raises ConfigError naming the
    spec when the import, the lookup or the constructor fails."""
    if not re.match(SPEC_PATTERN, factory):
        raise ConfigError(f"poller factory {factory!r} is not 'module:Class'")
    module_name, _, attr = factory.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(f"poller factory {factory!r}: cannot import {module_name}: {exc}") from exc
    cls = getattr(module, attr, None)
    if cls is None:
        raise ConfigError(f"poller factory {factory!r}: {module_name} has no {attr}")
    try:
        poller = cls(**(kwargs or {}))
    except Exception as exc:
        raise ConfigError(f"poller factory {factory!r}: constructor failed: {type(exc).__name__}: {exc}") from exc
    missing = [m for m in ("open", "read", "close") if not callable(getattr(poller, m, None))]
    if missing:
        raise ConfigError(f"poller factory {factory!r}: the object has no {', '.join(missing)}()")
    return poller


def probe(factory: str, kwargs: dict[str, Any] | None, n_channels: int, reads: int = 3) -> list[tuple[float, ...]]:
    """Build, open, read ``reads`` times and close a poller here, in this process: a
    quick check of a new poller (against its device or an emulator) before it runs in
    the sampler. Raises ConfigError when a read returns the wrong number of values or
    something that is not a number; open and read errors propagate as they are."""
    poller = load_poller(factory, kwargs)
    poller.open()
    try:
        rows = []
        for _ in range(reads):
            raw = poller.read()
            try:
                row = tuple(float(x) for x in raw)
            except (TypeError, ValueError) as exc:
                raise ConfigError(f"poller {factory!r}: read() returned {raw!r}, not numbers") from exc
            if len(row) != n_channels:
                raise ConfigError(f"poller {factory!r}: read() returned {len(row)} values for {n_channels} channel(s)")
            rows.append(row)
        return rows
    finally:
        poller.close()
