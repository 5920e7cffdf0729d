"""Names the command line offers, in a module with no imports: its parsers are built
from them without loading pydantic, numpy or scipy."""

from __future__ import annotations

FIT_DEGREE = {"linear": 1, "poly2": 2, "poly3": 3}

# feature name -> (CycleResult attribute, unit at the edge, scale from SI to that unit)
FEATURES: dict[str, tuple[str, str, float]] = {
    "p_eq": ("p_eq", "kPa", 1e-3),
    "v_eq": ("v_eq", "ml", 1e6),
    "dp_eq": ("dp_eq", "kPa", 1e-3),
    "dp_max": ("dp_max", "kPa", 1e-3),
    "t_c_slope": ("t_c_slope", "s", 1.0),
    "t_c_threshold": ("t_c_threshold", "s", 1.0),
    "t_c2": ("t_c2", "s", 1.0),
    "t_c_onset": ("t_c_onset", "s", 1.0),
}
NEEDS_REFERENCE = {"dp_eq", "dp_max", "t_c_slope", "t_c_threshold", "t_c2", "t_c_onset"}

#: the command socket's requests (controller/requests/server.py)
COMMANDS = ("status", "cycle", "grip", "release", "measure", "abort", "reset", "scene", "task", "shutdown")
