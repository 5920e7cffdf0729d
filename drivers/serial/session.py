"""What the serial link decides about its device: whether the device fits the config
(checked at every connection, from its INFO), and when damaged frames are too many."""

from __future__ import annotations

from collections import deque

from fluidsense.common.errors import ConfigError

from . import protocol as p
from .config import SerialDriverConfig


def check_fit(cfg: SerialDriverConfig, info: p.Info) -> None:
    """A device that cannot do what the config asks is a bad setting, not a link to retry."""
    w = cfg.wiring
    problems = []
    if info.version != p.PROTO_VERSION:
        problems.append(f"it speaks protocol {info.version}, this driver {p.PROTO_VERSION}: flash firmware/")
    if info.adc_bits != cfg.adc.bits:
        problems.append(f"its ADC has {info.adc_bits} bits, driver.adc.bits says {cfg.adc.bits}")
    if max(s.adc for s in w.sensors.values()) >= info.n_adc:
        problems.append(f"it has analog inputs 0-{info.n_adc - 1}")
    if max(v.output for v in w.valves.values()) >= info.n_outputs:
        problems.append(f"it has digital outputs 0-{info.n_outputs - 1}")
    if w.regulator is not None and w.regulator.analog_output >= info.n_aout:
        problems.append(f"it has {info.n_aout} analog outputs")
    if cfg.rate_hz > info.max_rate_hz:
        problems.append(f"it samples at most {info.max_rate_hz} Hz, driver.rate_hz is {cfg.rate_hz}")
    if problems:
        raise ConfigError(f"driver: the device on {cfg.port} ({info.board}) does not fit this config: "
                          + "; ".join(problems))


class DamageWindow:
    """Frames lost or corrupt within the last second. Each costs its own sample; more than
    ``limit`` of them make the link unusable, said at most every 10 s (a bad cable would
    otherwise latch a fault at every frame)."""

    def __init__(self, limit: int):
        self.limit = limit
        self._events: deque[tuple[float, int]] = deque()
        self._told = -1e9

    def add(self, n: int, t: float) -> int | None:
        """Count ``n`` damaged frames at ``t`` (s); the window's total when it is over the
        limit and not said in the last 10 s, else None."""
        self._events.append((t, n))
        while self._events[0][0] < t - 1.0:
            self._events.popleft()
        total = sum(c for _, c in self._events)
        if total > self.limit and t - self._told > 10.0:
            self._told = t
            return total
        return None
