"""The simulated cell as a backend: device adapters over simulator/ (imported only when a
config selects ``driver: sim``)."""

from .backend import SimBackend, build

__all__ = ["SimBackend", "build"]
