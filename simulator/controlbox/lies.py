"""A hostile box: what the emulator says on the wire that a real box cannot say (sim
control ``lie``), so that the driver's checks of every field meet a real peer.

A lie lasts ``count`` packages or replies that it changes (counted, not timed: a box
stalled on a loaded machine still tells all of it), then the box is sane again (a glitch
that passes, after which ``reset`` must work). While it lasts:

- ``analog_nan`` / ``analog_inf`` / ``analog_range``: RTDE's ``standard_analog_input0``
  and ``1`` read NaN, +inf or 1000 (V or mA: no UR analog input measures that);
- ``timestamp_forward`` / ``timestamp_back``: RTDE's ``timestamp`` is 1000 s ahead of the
  box's clock, or 1 s behind the last one sent;
- ``timestamp_fast``: ``timestamp`` runs ten times as fast as the box's clock (a stream
  claiming ten times its stated rate);
- ``timestamp_stall``: ``timestamp`` stands still while the packages keep coming;
- ``modbus_extra`` / ``modbus_short``: a Modbus read of holding registers is answered
  with one register more, or one fewer, than it asked for.
"""

from __future__ import annotations

import logging
import math
from typing import Any

log = logging.getLogger(__name__)

KINDS = ("analog_nan", "analog_inf", "analog_range", "timestamp_forward", "timestamp_back", "timestamp_fast",
         "timestamp_stall", "modbus_extra", "modbus_short")
_ANALOG = {"analog_nan": math.nan, "analog_inf": math.inf, "analog_range": 1000.0}
_ANALOG_NAMES = ("standard_analog_input0", "standard_analog_input1")


class Lies:
    def __init__(self) -> None:
        self.kind: str | None = None
        self.since = 0.0  # box time the lie began
        self.left = 0  # packages or replies still to change
        self.told = 0  # packages or replies changed, over every lie

    def tell(self, kind: str, now: float, count: int) -> None:
        if kind not in KINDS:
            raise ValueError(f"lie: {kind!r} is not one of {', '.join(KINDS)}")
        self.kind, self.since, self.left = kind, now, count
        log.warning("sim control: the box lies (%s) in %d packages or replies", kind, count)

    def state(self) -> dict[str, Any]:
        return {"kind": self.kind, "left": self.left, "told": self.told}

    def _one(self) -> None:
        self.told += 1
        self.left -= 1
        if self.left <= 0:
            log.warning("sim control: the box's lie (%s) is over", self.kind)
            self.kind = None

    def rtde(self, names: list[str], values: list[Any], t: float) -> list[Any]:
        """An RTDE output package's values as the lie sends them, at box time ``t``."""
        kind = self.kind
        if kind is None:
            return values
        out = list(values)
        for i, name in enumerate(names):
            if kind in _ANALOG and name in _ANALOG_NAMES:
                out[i] = _ANALOG[kind]
            elif name == "timestamp" and kind.startswith("timestamp"):
                out[i] = {"timestamp_forward": out[i] + 1000.0, "timestamp_back": self.since - 1.0,
                          "timestamp_fast": self.since + 10.0 * (out[i] - self.since),
                          "timestamp_stall": self.since}[kind]
        if out != values:
            self._one()
        return out

    def modbus(self, t: float, registers: list[int]) -> list[int]:
        """The registers a Modbus read reply carries under the lie."""
        kind = self.kind
        if kind == "modbus_extra":
            self._one()
            return [*registers, 0]
        if kind == "modbus_short" and registers:
            self._one()
            return registers[:-1]
        return registers
