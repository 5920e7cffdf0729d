"""Simulated pneumatic cell (imported only when a config selects ``driver: sim``)."""

from .backend import SimCell, build

__all__ = ["SimCell", "build"]
