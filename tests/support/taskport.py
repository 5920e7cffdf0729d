"""A fake cell behind the tasks' port (controller/ports.py TaskPort): no controller, no
sockets, no process. A task holds its port and nothing else, so it runs here as it runs on
a controller; the fake writes down what it was asked (``asked``) and answers each cycle
with what ``reading`` says of the scene in place (P_eq, kPa), in its own sample time.

What a test's task does not use raises, naming the member: a task that reaches for more
than the fake gives fails loudly instead of passing on a default.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from fluidsense.common.faults import Fault
from fluidsense.common.units import KPA
from fluidsense.controller.config import Profile
from fluidsense.controller.cycles.analysis import CycleResult, Reference, WindowResult
from fluidsense.controller.ports import TaskPort

CYCLE_S = 25.0  # sample time a cycle takes here (charge, isolate, windows)


@dataclass
class FakeTaskCell:
    profile: Profile
    reading: Callable[[Any], float]  # the scene in place -> its P_eq (kPa)
    t: float = 0.0
    scene: Any = None
    fault: Fault | None = None
    references: dict[float, Reference] = field(default_factory=dict)  # by P0 in Pa
    asked: list[tuple] = field(default_factory=list)
    events: list[tuple[str, dict[str, Any]]] = field(default_factory=list)
    _cycle_id: int = 0

    async def place(self, scene: Any) -> None:
        self.asked.append(("place", scene))
        self.scene = scene

    async def run_cycle(self, *, p0_kpa: float | None = None, label: str | None = None,
                        store_reference: bool = False) -> CycleResult:
        self.asked.append(("run_cycle", p0_kpa, label, store_reference))
        self._cycle_id += 1
        p0 = (self.profile.sequence.p0_kpa if p0_kpa is None else p0_kpa) * KPA
        w = self.profile.sequence.windows[0]
        t0, self.t = self.t, self.t + CYCLE_S
        window = WindowResult(w.name, w.start_s, w.end_s, self.reading(self.scene) * KPA, 10.0, 1000)
        return CycleResult(self._cycle_id, p0, t0, t0 + 1.0, self.t, windows=[window])

    def emit(self, topic: str, payload: dict[str, Any]) -> None:
        self.events.append((topic, payload))

    def port(self) -> TaskPort:
        def unused(name: str):
            def refuse(*args: Any, **kwargs: Any):
                raise AssertionError(f"the fake task cell has no {name}: the task under test asked for it")
            return refuse

        return TaskPort(profile=self.profile, now=lambda: self.t, run_cycle=self.run_cycle,
                        start_cycle=unused("start_cycle"), measured=unused("measured"), release=unused("release"),
                        wait_after_open=unused("wait_after_open"), reference=self.references.get,
                        fault=lambda: self.fault, emit=self.emit, simulated=True, place=self.place,
                        lay_out=unused("lay_out"), truth=unused("truth"), move_l=unused("move_l"),
                        tcp_pose=unused("tcp_pose"))
