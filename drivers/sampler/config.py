"""Configuration of a polled source sampled in its own process (docs/architecture.md, decision 3)."""

from __future__ import annotations

from typing import Annotated, Literal

from fluidsense.common.models import Integer, Real, StrictModel
from pydantic import Field, JsonValue, model_validator

from .poller import SPEC_PATTERN

ChannelName = Annotated[str, Field(pattern=r"^[A-Za-z_][A-Za-z0-9_]*$", max_length=64)]


class PollerSpec(StrictModel):
    """Which poller the sampler process builds: ``Class(**kwargs)`` from ``module:Class``."""

    factory: str = Field(pattern=SPEC_PATTERN, description="'module:Class', imported inside the sampler process",
                         examples=["fluidsense.drivers.sampler.synthetic:SyntheticPoller"])
    kwargs: dict[str, JsonValue] = Field(default_factory=dict, description="JSON keyword arguments")


class SamplerOptions(StrictModel):
    """The real-time settings of a sampler process, which a production driver's config
    exposes as its ``sampler`` section (docs/sampler.md); the poller and the channels come
    from the driver."""

    late_threshold_us: Real = Field(
        50.0, gt=0, description="a read that starts more than this after its slot's deadline counts as late")
    spin_us: Real = Field(75.0, ge=0, le=10_000,
                           description="sleep until this long before a deadline, then spin to it (75 us: "
                           "docs/performance.md, spin against lateness and CPU)")
    link_timeout_s: Real = Field(
        0.25, gt=0, le=60, description="reads failing in a row for this long (at least twice) mean the link is "
        "lost and the driver reconnects; shorter trouble (a busy box, a late reply) costs missed slots only. "
        "Below supervision.no_data_s (0.5 s), so the reconnection starts by the time the cell faults")
    cpu: Literal["auto", "none"] | Annotated[Integer, Field(ge=0, le=4095)] = Field(
        "auto", description="CPU to pin the sampler thread to; auto: the last allowed CPU; none: do not pin")
    rt_priority: Annotated[Integer, Field(ge=1, le=99)] | None = Field(
        40, description="SCHED_FIFO priority when permitted (null: normal scheduling). 40 stays below "
        "the kernel's threaded interrupt handlers (50), which a network poller depends on")
    silence_timeout_s: Real = Field(1.0, gt=0, le=600,
                                     description="no message from the sampler for this long means it is gone")


class SamplerConfig(SamplerOptions):
    """A polled source: one read of every channel per slot, in a dedicated process."""

    poller: PollerSpec
    channels: tuple[ChannelName, ...] = Field(min_length=1, max_length=64,
                                              description="names of the values read() returns, in order")
    rate_hz: Real = Field(1000.0, gt=0, le=10_000, description="slots per second")
    block_size: Integer = Field(10, ge=1, le=10_000, description="samples per block handed to the daemon")
    start_timeout_s: Real = Field(30.0, gt=0, le=600,
                                   description="time allowed to spawn the process and open the poller")
    stop_timeout_s: Real = Field(2.0, gt=0, le=60, description="time allowed for a clean stop before SIGTERM")

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    @model_validator(mode="after")
    def _fits_the_period(self) -> SamplerConfig:
        period_us = 1e6 / self.rate_hz
        if self.late_threshold_us >= period_us:
            raise ValueError(f"late_threshold_us ({self.late_threshold_us:g}) must be below the period "
                             f"({period_us:g} us at {self.rate_hz:g} Hz): a read started one period late is missed")
        if self.spin_us >= period_us:
            raise ValueError(f"spin_us ({self.spin_us:g}) must be below the period ({period_us:g} us): "
                             "the loop would never sleep")
        if len(set(self.channels)) != len(self.channels):
            raise ValueError(f"channel names must be unique, got {list(self.channels)}")
        return self
