"""The start of every connection to the serial device: HELLO, what the device is, START."""

from __future__ import annotations

import logging
import random
from collections.abc import Callable
from typing import TYPE_CHECKING

from fluidsense.common.errors import ConfigError, DeviceTimeoutError, DriverError

from . import protocol as p
from .session import check_fit

if TYPE_CHECKING:
    from .link import SerialLink

log = logging.getLogger(__name__)


async def handshake(link: SerialLink, start: Callable[[int], bytes], previous_session: int | None) -> p.Info:
    """HELLO until the device answers (an Arduino restarts when its port opens; its
    bootloader takes 1-2 s), check what it is, START a new session."""
    cfg = link.cfg
    while True:
        try:
            await link.command(p.HELLO, tries=1, timeout_s=max(0.25, cfg.ack_timeout_s))
            break
        except DeviceTimeoutError:
            continue  # bounded by the source's connect timeout
    info = link.info
    if info is None:
        raise DriverError(f"{link.name}: HELLO acknowledged without INFO")
    check_fit(cfg, info)
    session = random.choice([s for s in range(1, 256) if s != previous_session])
    link.session = session
    link.timeline.new_session()
    try:
        await link.command(p.START, start(session))
    except DriverError as exc:
        if "argument refused" in str(exc):
            raise ConfigError(f"driver: the device refused the configuration (rate {cfg.rate_hz} Hz, "
                              f"channels, heartbeat): {exc}") from exc
        raise
    log.info("%s: session %d started on %s (%s reset, %d-bit ADC)", link.name, session, info.board,
             info.reset_cause, info.adc_bits)
    return info
