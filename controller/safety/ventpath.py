"""What vents the gripper when the link to the device dies, or the daemon with it, and
for how long it can stay pressurised where nothing does: the driver says what it has
(``DriverEntry.dead_link_vent``), the cell config how long the daemon takes to see the
loss and to come back. ``status`` carries it, ``fluidsense check`` says it
(docs/safety.md, "Vent without the PC").
"""

from __future__ import annotations

from typing import Any

from ..config import CellConfig


def vent_path(cfg: CellConfig) -> dict[str, Any]:
    """The cell's vent path on a dead link, for ``status`` and ``check``: ``by`` (``box_watchdog``,
    ``device_watchdog``, ``none``, ``no_link``), ``what``, ``timeout_s`` (the vent after the
    last heartbeat), and where nothing vents: ``fault_after_s`` (the daemon's no_data fault:
    it faults, but cannot vent what it cannot reach), ``after_link_returns_s`` (the
    reconnection back-off's longest wait: the next attempt writes the safe state first),
    ``pressurised`` (in words) and ``fix``."""
    v = cfg.driver.dead_link_vent()
    out: dict[str, Any] = {"by": v.by, "what": v.what, "timeout_s": v.timeout_s, "fault_after_s": None,
                           "after_link_returns_s": None, "pressurised": None, "fix": v.fix}
    if v.by in ("box_watchdog", "device_watchdog"):
        out["pressurised"] = (f"at most {v.timeout_s:g} s after the daemon's last heartbeat, then the gripper's own "
                              "vent time")
    elif v.by == "none":
        fault = cfg.supervision.no_data_s
        out["fault_after_s"] = fault
        back = "" if v.reconnect_max_s is None else (
            f", plus up to {v.reconnect_max_s:g} s (reconnect.max_s) until the daemon's next reconnection attempt, "
            "which writes the safe state first")
        out["after_link_returns_s"] = v.reconnect_max_s
        out["pressurised"] = (f"until the link returns{back}: the daemon faults within {fault:g} s "
                              "(supervision.no_data_s) but cannot vent a device it cannot reach; a daemon that "
                              "dies: until it runs and connects again")
    return out


def vent_path_line(path: dict[str, Any]) -> str:
    """One line for an operator: what vents, or that nothing does, how long, and the fix."""
    if path["by"] == "none":
        return (f"nothing vents the gripper when the link or the daemon dies: {path['what']}; it can stay "
                f"pressurised {path['pressurised']}" + (f". Fix: {path['fix']}" if path["fix"] else ""))
    if path["by"] == "no_link":
        return path["what"]
    return f"{path['what']}: pressurised {path['pressurised']}"
