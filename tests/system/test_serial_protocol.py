"""The serial streamer's protocol without a device: the firmware core's own unit tests (C,
built and run here), the host side's framing against the same definitions, the clock
alignment, and the config's refusals.

(Its in-process tests: tests/unit/test_serial_protocol.py.)
"""

from __future__ import annotations

import subprocess
from support.harness import REPO


def test_the_firmware_core_passes_its_unit_tests():
    """CRC, COBS (every length), commands and acks, retries, sample frames, dropped frames,
    the heartbeat watchdog's exact timeout, ARM, STOP: firmware/tests/test_core.c."""
    out = subprocess.run(["make", "-s", "-C", str(REPO / "firmware"), "test-core"], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    last = out.stdout.strip().splitlines()[-1]
    passed, failed = (int(w) for w in last.replace(",", "").split()[::2])
    assert failed == 0 and passed >= 20, out.stdout
