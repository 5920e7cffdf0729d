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
  with one register more, or one fewer, than it asked for;
- ``modbus_domain``: a read of the analog inputs says their domain registers (5, 7) read
  7, which is no domain (0 current, 1 voltage);
- ``freeze``: the box's inputs stand still for ``count`` I/O cycles (500 per second on an
  e-Series): its I/O image is not refreshed, so Modbus and RTDE report the values of the
  cycle before, as a box whose I/O stalled would. Not a lie a single reply can show: a
  freeze longer than the supervisor's ``stuck_s`` is a ``sensor_stuck`` fault, a shorter
  one marks the cycle's reading unreliable (controller/cycles/frozen.py).

A lie may wait for the box's outputs (``on_output``, ``delay_s``): it is armed, and begins
``delay_s`` of box time after digital output ``on_output`` next turns on (the actuation
valve opening), so that it lands at a chosen moment of a cycle whatever the load.
"""

from __future__ import annotations

import logging
import math
from typing import Any

log = logging.getLogger(__name__)

KINDS = ("analog_nan", "analog_inf", "analog_range", "timestamp_forward", "timestamp_back", "timestamp_fast",
         "timestamp_stall", "modbus_extra", "modbus_short", "modbus_domain", "freeze")
#: a domain register's value that is no domain (0 current, 1 voltage)
BAD_DOMAIN = 7
_ANALOG = {"analog_nan": math.nan, "analog_inf": math.inf, "analog_range": 1000.0}
_ANALOG_NAMES = ("standard_analog_input0", "standard_analog_input1")


class Lies:
    def __init__(self) -> None:
        self.kind: str | None = None
        self.since = 0.0  # box time the lie began
        self.left = 0  # packages or replies still to change
        self.told = 0  # packages or replies changed, over every lie
        #: a lie waiting for an output: (kind, count, output, delay_s)
        self.armed: tuple[str, int, int, float] | None = None

    def tell(self, kind: str, now: float, count: int, on_output: int | None = None, delay_s: float = 0.0) -> None:
        if kind not in KINDS:
            raise ValueError(f"lie: {kind!r} is not one of {', '.join(KINDS)}")
        if on_output is not None:
            self.kind, self.armed = None, (kind, count, on_output, delay_s)
            log.warning("sim control: the box will lie (%s) %g s after output %d turns on", kind, delay_s, on_output)
            return
        self.armed = None
        self.kind, self.since, self.left = kind, now + delay_s, count
        log.warning("sim control: the box lies (%s) in %d packages, replies or I/O cycles", kind, count)

    def outputs_changed(self, t: float, before: int, after: int) -> None:
        """The box's digital outputs changed at box time ``t``: an armed lie may begin."""
        if self.armed is not None:
            kind, count, output, delay_s = self.armed
            if after >> output & 1 and not before >> output & 1:
                self.tell(kind, t, count, delay_s=delay_s)

    def state(self) -> dict[str, Any]:
        return {"kind": self.kind, "left": self.left, "told": self.told,
                "armed": None if self.armed is None else self.armed[0]}

    def frozen(self, t: float, cycles: int) -> bool:
        """The box begins ``cycles`` new I/O cycles at box time ``t``: True while the
        freeze holds its image (the refresh is skipped), counted in cycles."""
        if self.kind != "freeze" or t < self.since:
            return False
        self.left -= cycles
        self.told += cycles
        if self.left <= 0:
            log.warning("sim control: the box's lie (freeze) is over")
            self.kind = None
        return self.left >= 0

    def _one(self) -> None:
        self.told += 1
        self.left -= 1
        if self.left <= 0:
            log.warning("sim control: the box's lie (%s) is over", self.kind)
            self.kind = None

    def rtde(self, names: list[str], values: list[Any], t: float) -> list[Any]:
        """An RTDE output package's values as the lie sends them, at box time ``t``."""
        kind = self.kind
        if kind is None or t < self.since:
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

    def modbus(self, t: float, registers: list[int], address: int = 4) -> list[int]:
        """The registers a Modbus read reply from ``address`` carries under the lie."""
        kind = self.kind
        if kind is None or t < self.since:
            return registers
        if kind == "modbus_domain":
            domains = [i for i in (5 - address, 7 - address) if 0 <= i < len(registers)]
            if not domains:
                return registers
            self._one()
            return [BAD_DOMAIN if i in domains else r for i, r in enumerate(registers)]
        if kind == "modbus_extra":
            self._one()
            return [*registers, 0]
        if kind == "modbus_short" and registers:
            self._one()
            return registers[:-1]
        return registers
