"""Sampler settings and the spec of the poller it builds in its own process."""

from __future__ import annotations

import importlib
from typing import Any

from pydantic import Field, field_validator

from ..errors import ConfigError
from ..models import StrictModel


class PollerSpec(StrictModel):
    """``target`` is ``"module:Class"``; the class is built in the sampler process with
    ``kwargs`` (JSON values only: the spec crosses a process boundary as JSON)."""

    target: str = Field(pattern=r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$")
    kwargs: dict[str, Any] = Field(default_factory=dict)

    def build(self):
        module, _, name = self.target.partition(":")
        try:
            cls = getattr(importlib.import_module(module), name)
        except (ImportError, AttributeError) as exc:
            raise ConfigError(f"poller {self.target!r} cannot be imported: {exc}") from exc
        return cls(**self.kwargs)


class SamplerConfig(StrictModel):
    rate_hz: float = Field(1000.0, gt=0, le=5000)
    block_size: int = Field(10, ge=1, le=1000)
    late_threshold_us: float = Field(
        100.0, gt=0, le=1e6, description="a read that starts later than this after its slot is late (its "
        "timestamp stays exact; late only means off the grid). 100 us is a tenth of a 1 kHz period")
    spin_us: float = Field(200.0, ge=0, le=10_000, description="sleep until this long before a deadline, then spin")
    cpu: int | None = Field(None, ge=0, le=1023, description="pin the sampler to this CPU")
    realtime_priority: int | None = Field(
        None, ge=1, le=99, description="SCHED_FIFO priority; applied when permitted (else a log line says why not)")
    silence_timeout_s: float = Field(1.0, gt=0, le=60, description="no block for this long: the link is lost")
    max_consecutive_failures: int = Field(10, ge=1, le=100_000)
    start_timeout_s: float = Field(10.0, gt=0, le=120)

    @field_validator("rate_hz")
    @classmethod
    def _block_rate(cls, v: float) -> float:
        return float(v)

    @property
    def period_ns(self) -> int:
        return int(round(1e9 / self.rate_hz))
