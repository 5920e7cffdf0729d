"""The contact time as the command line shows it: always with its method beside it.

A cycle result carries two contact times (docs/zmq-schema.md): ``t_c_threshold_s``, when
dP first crosses the profile's contact threshold (what the gripper's events report as
``t_c_s``), and ``t_c_slope_s``, the change of slope of dP before that crossing (earlier:
how the paper finds the time of first contact, its Methods "Time of first contact"). They differ by design, so a value
without its method invites comparing the two."""

from __future__ import annotations

from typing import Any

#: result key -> the method's name as shown
METHODS = {"t_c_threshold_s": "threshold", "t_c_slope_s": "slope"}


def t_c_text(result: dict[str, Any], key: str = "t_c_threshold_s") -> str | None:
    """``t_c 0.107 s (threshold)``, or None when the cycle has no such contact time."""
    value = result.get(key)
    return None if value is None else f"t_c {value:.3f} s ({METHODS[key]})"
