"""The simulated work cell: what the gripper holds, where objects are.

Closing the gripper at a slot takes the object in it (the pneumatic scene becomes that
object); moving away while the grip is too weak leaves it behind; opening the gripper at
a slot puts the held object there, anywhere else drops it. A grip centres an off-centre
object; an object set to slip does so a while after the grip. Every such event is kept
in ``events`` for the tasks' self-scoring.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any

from fluidsense.common.scenes import CylinderScene, EmptyScene
from fluidsense.common.world import WorldObject, WorldSpec

log = logging.getLogger(__name__)


@dataclass
class World:
    spec: WorldSpec
    content: dict[str, str | None] = field(init=False)
    objects: dict[str, WorldObject] = field(init=False)
    holding: str | None = None  # object in the (closed) gripper
    from_slot: str | None = None
    slipped: bool = False
    closed: bool = False
    events: list[dict[str, Any]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.content = {s.name: s.object for s in self.spec.slots}
        self.objects = {o.name: o for o in self.spec.objects}
        self._poses = {s.name: s.pose for s in self.spec.slots}

    def slot_at(self, pose) -> str | None:
        reach = self.spec.reach_mm * 1e-3
        best, dist = None, math.inf
        for name, p in self._poses.items():
            d = math.dist(pose[:3], p[:3])
            if d <= reach and d < dist:
                best, dist = name, d
        return best

    def scene_of(self, name: str | None):
        if name is None:
            return EmptyScene()
        obj = self.objects[name]
        if self.slipped:
            return CylinderScene(diameter_mm=obj.slip_diameter_mm)
        return CylinderScene(diameter_mm=obj.diameter_mm, offset_mm=obj.offset_mm,
                             stiffness_n_per_mm=obj.stiffness_n_per_mm,
                             relaxed_stiffness_n_per_mm=obj.relaxed_stiffness_n_per_mm, creep_s=obj.creep_s)

    def _event(self, t: float, what: str, **info: Any) -> None:
        self.events.append({"t_s": t, "event": what, **info})
        log.debug("world t=%.3f: %s %s", t, what, info)

    # ---------------------------------------------------------------- gripper
    def close(self, pose, t: float):
        """The gripper closes at ``pose``; returns the scene it closes on."""
        self.closed = True
        slot = self.slot_at(pose)
        name = self.content.get(slot) if slot is not None else None
        self.holding, self.from_slot, self.slipped = name, slot, False
        self._event(t, "close", slot=slot, object=name)
        return self.scene_of(name)

    def open(self, pose, t: float):
        """The gripper opens at ``pose``; the held object goes into the slot there."""
        self.closed = False
        name, self.holding = self.holding, None
        if name is None:
            self._event(t, "open", slot=self.slot_at(pose), object=None)
            return EmptyScene()
        slot = self.slot_at(pose)
        obj = self.objects[name]
        if slot == self.from_slot:  # released where it was taken: it just stays
            self.content[slot] = name
        elif slot is not None and self.content[slot] is None:
            self.content[slot] = name
            if self.from_slot is not None and self.content.get(self.from_slot) == name:
                self.content[self.from_slot] = None
        else:
            self._event(t, "dropped", object=name, at=slot)
            if self.from_slot is not None and self.content.get(self.from_slot) == name:
                self.content[self.from_slot] = None
            slot = None
        if obj.offset_mm and slot is not None:  # gripped once: now centred where it lies
            self.objects[name] = obj.model_copy(update={"offset_mm": 0.0})
        self._event(t, "open", slot=slot, object=name)
        self.from_slot, self.slipped = None, False
        return EmptyScene()

    def move_away(self, t: float, margin_kpa: float):
        """The arm starts moving with the gripper closed. Returns a new scene when the
        object stays behind (grip too weak), else None."""
        if self.holding is None or self.from_slot is None or self.content.get(self.from_slot) != self.holding:
            return None  # nothing held, or already carried off
        obj = self.objects[self.holding]
        if margin_kpa < obj.min_grip_kpa:
            self._event(t, "not_held", object=self.holding, margin_kpa=margin_kpa, needed_kpa=obj.min_grip_kpa)
            self.holding = None
            return EmptyScene()
        self.content[self.from_slot] = None  # picked: it travels with the gripper
        self._event(t, "picked", object=obj.name, slot=self.from_slot, margin_kpa=margin_kpa)
        return None

    def slip(self, t: float):
        """A held object slips into the palm (scheduled by the cell)."""
        if self.holding is None or self.slipped:
            return None
        self.slipped = True
        self._event(t, "slipped", object=self.holding)
        return self.scene_of(self.holding)

    def truth(self) -> dict[str, Any]:
        return {"content": dict(self.content), "holding": self.holding, "slipped": self.slipped,
                "events": list(self.events)}
