"""Polled sources sampled in a dedicated process (docs/architecture.md, decision 3).

- :mod:`.poller`: the interface a device reader implements (built inside the process);
- :mod:`.synthetic`: a synthetic poller for tests and benchmarks;
- :mod:`.slots`: the slot loop (absolute deadlines, sleep then spin, on time / late /
  missed / failed accounting), with an injectable clock;
- :mod:`.process`: the process entry point (real-time settings, ZeroMQ PUSH);
- :mod:`.source`: ``SampledSource``, the daemon's side;
- :mod:`.config`: ``SamplerConfig`` and its real-time part ``SamplerOptions`` (a driver config's ``sampler`` section).

The daemon-side names are imported lazily so that the sampler process, which imports
this package on its way to ``.process``, loads neither pydantic nor zmq.asyncio.
"""

from __future__ import annotations

from typing import Any

__all__ = ["Poller", "PollerSpec", "SampledSource", "SamplerConfig", "SyntheticPoller", "load_poller"]

_LAZY = {
    "Poller": ".poller", "load_poller": ".poller", "SyntheticPoller": ".synthetic",
    "SampledSource": ".source", "SamplerConfig": ".config", "PollerSpec": ".config",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
