"""What ``status`` answers and what the heartbeat carries: the controller's state read
from its parts (no state of its own)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ..safety.latch import vented_word

if TYPE_CHECKING:
    from ..service import Controller


def status_of(ctrl: Controller) -> dict[str, Any]:
    seq, valves, fault = ctrl.cycles.sequencer, ctrl.backend.valves, ctrl.fault
    return {
        "state": seq.state.value if ctrl.connected else "connecting", "connecting": ctrl.connecting,
        "cycle_id": seq.cycle_id, "t_s": ctrl.now, "virtual": ctrl.virtual, "backend": ctrl.backend.name,
        "profile": ctrl.profile.name,
        "fault": None if fault is None else {"kind": fault.kind, "detail": fault.detail, "t_s": fault.t},
        "valves": valves.reported, "valves_age_s": valves.age_s(), "valves_commanded": valves.state,
        "vented": vented_word(ctrl.latch.vented()), "references_kpa": sorted(ctrl.cycles.references),
        "samples": ctrl.loop.samples, "missed": ctrl.loop.missed,
        "last_cycle": ctrl.cycles.results[-1].to_dict() if ctrl.cycles.results else None,
        "task": ctrl.commands.task, "commands": None if ctrl.command_stats is None else ctrl.command_stats(),
        "publisher": ctrl.telemetry.pub.stats, **ctrl.commands.gripper.status(),
        "sinks": [sink.stats for sink in ctrl.telemetry.sinks if hasattr(sink, "stats")],
        # a source that keeps link counts (the serial driver: frames lost and corrupt, resets, clock drift)
        "source_link": getattr(ctrl.backend.source, "link_stats", lambda: None)(),
    }


def heartbeat_of(ctrl: Controller) -> dict[str, Any]:
    """The heartbeat's fields: the few a watcher needs every second."""
    seq, loop = ctrl.cycles.sequencer, ctrl.loop
    return {"state": seq.state.value, "cycle_id": seq.cycle_id,
            "fault": None if ctrl.fault is None else ctrl.fault.kind, "samples": loop.samples,
            "blocks": loop.blocks, "missed": loop.missed, "late": loop.late,
            "rate_hz": ctrl.backend.source.rate_hz, "virtual": ctrl.virtual}
