"""The AVR image's long runs in simavr (Debian's gcc-avr, avr-libc, simavr and
libsimavr-dev; `make accept` installs them as root, and without them the run is skipped,
saying why): the sorting cycles through the serial driver that tests/system/test_serial.py
runs on the host board, here on the ATmega328P image, about half a minute of real time in
the simulator. The AVR's short checks (the round trip, tick 0, the vent when the daemon
dies, the hardware watchdog) stay in the system tier beside the host board's."""

from __future__ import annotations

import pytest
from support.serial import needs_avr
from system.test_serial import simserial  # noqa: F401 - the fixture the run below takes
from system.test_serial import (
    test_sorting_cycles_through_the_serial_driver_read_sensible_pressures as sorting_cycles,
)

# half a minute of the simulated MCU on a quiet machine, several times that beside other work
pytestmark = [needs_avr, pytest.mark.timeout(600)]


def test_sorting_cycles_on_the_avr_image_read_sensible_pressures(tmp_path, simserial):
    sorting_cycles(tmp_path, simserial, "avr")
