"""Samples as they travel from a source to the controller, and the clock they define.

Every sample carries its timestamp (sample time, s); the controller's "now" is the
newest sample's (docs/architecture.md, decision 2).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass(frozen=True, slots=True)
class SampleBlock:
    """A block of timestamped samples, all channels sampled at the same instants.

    ``values[i, j]`` is channel ``channels[j]`` at time ``t[i]``, in SI units (Pa gauge for
    pressure channels, standard m^3/s for flow channels). ``missed`` counts sample slots
    that the source could not fill before this block; they are reported, never
    interpolated. ``late`` counts samples in this block taken after their slot deadline
    (polled sources only).
    """

    seq: int
    t: np.ndarray
    values: np.ndarray
    channels: tuple[str, ...]
    missed: int = 0
    late: int = 0
    lateness_s: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.values.shape != (len(self.t), len(self.channels)):
            raise ValueError(
                f"block values shape {self.values.shape} does not match "
                f"{len(self.t)} samples x {len(self.channels)} channels"
            )

    def __len__(self) -> int:
        return len(self.t)

    def channel(self, name: str) -> np.ndarray:
        try:
            return self.values[:, self.channels.index(name)]
        except ValueError:
            raise KeyError(f"no channel {name!r} in block (have {self.channels})") from None

    @property
    def t_end(self) -> float:
        return float(self.t[-1])


class SampleClock(Protocol):
    """The controller's clock as devices see it: ``now`` is the newest sample's time and
    ``wait_until`` returns once samples have reached a time. A simulated arm moves in this
    time (in virtual time nothing else would advance it)."""

    @property
    def now(self) -> float: ...

    async def wait_until(self, t: float) -> None: ...
