"""The recording's settings: where and how the daemon records (a cell config's
``recording:`` section) and the replay driver's entry (``driver: {kind: replay}``)."""

from __future__ import annotations

from typing import ClassVar, Literal

from fluidsense.common.models import Real, StrictModel
from pydantic import Field

from ..entry import DeadLinkVent, DriverEntry


class RecordingConfig(StrictModel):
    """What the daemon writes to disk (docs/recording.md): every sample block and event,
    and the config, in MCAP files named by their start time in ``dir``."""

    enabled: bool = Field(True, description="the daemon records (fluidsense run --no-record turns it off)")
    dir: str = Field("runs", min_length=1, description="directory of the recordings, relative to the "
                     "daemon's working directory; created if missing")
    flush_s: Real = Field(1.0, gt=0, le=10, description="sample time between flushes: a killed daemon "
                           "loses at most this much")
    fsync: bool = Field(True, description="also force each flush to storage (power loss), off the sample loop")
    compression: Literal["zstd", "lz4", "none"] = "zstd"
    max_file_mb: Real = Field(1024.0, gt=0, le=1_000_000, description="start a new file, between cycles, "
                               "once a file is this large")
    max_file_s: Real = Field(3600.0, gt=0, le=7 * 86400, description="start a new file, between cycles, "
                              "once a file covers this much sample time (the writer's index of a file stays "
                              "in memory until the file is closed: ~1 KB per flush)")
    min_free_mb: Real = Field(1024.0, ge=0, le=1_000_000, description="stop recording (and say so) when the "
                               "disk has less free space than this")


class ReplayDriverConfig(DriverEntry):
    """A recording (``fluidsense run`` writes them) played back in virtual time: its
    samples as they were delivered; valves cannot be commanded (docs/recording.md)."""

    backend_module: ClassVar[str] = "fluidsense.drivers.recording.backend"
    live: ClassVar[bool] = False

    kind: Literal["replay"] = "replay"
    file: str = Field(min_length=1, description="the recording (.mcap)")

    def files(self) -> dict[str, str]:
        return {"file": self.file}

    def dead_link_vent(self) -> DeadLinkVent:
        return DeadLinkVent("no_link", "a recording played back: no valve to vent")
