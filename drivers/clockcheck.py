"""The one rule every sample source applies to a device's clock: a device cannot have
taken more samples (or let more of its time pass) than the host's clock allows since a
common start, give or take the clock's tolerance. A sample cannot be read before it is
taken, so a host that reads late never trips it; only a start the host took late makes
the device look early, by at most the source's own margin. Each driver names the field
and words the error (serial ``rate``, RTDE ``timestamp``, DAQmx ``rate``)."""

from __future__ import annotations

#: how far a device's clock may run from the host's: a crystal is tens of ppm, a ceramic
#: resonator up to 0.5 %; four times that is still a clock at its rate
MAX_CLOCK_ERROR = 0.02


def lead_s(device_s: float, host_s: float, margin_s: float) -> float:
    """How far ``device_s`` of the device's time since the start leads ``host_s`` of the
    host's, beyond the tolerance and ``margin_s``: above 0 it cannot be true."""
    return device_s - host_s * (1 + MAX_CLOCK_ERROR) - margin_s
