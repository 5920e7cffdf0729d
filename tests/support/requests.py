"""A fake cell behind the request handlers' ports (controller/requests/ports.py): no
controller, no sockets, no subprocess; the handlers are the real ones, assembled as the
daemon assembles them (wiring.assemble).

The fake does at once what a handler asks and writes it down (``asked``); the test moves
the cycle along its course (``open``, ``measured``, ``hold``, ``end``) as the
controller's sequencer would, and feeds the gripper blocks of samples in the fake's own
sample time (``feed``): virtual time, nothing waits on a clock.
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from fluidsense.common.errors import SequenceError
from fluidsense.common.samples import SampleBlock
from fluidsense.common.units import KPA
from fluidsense.controller.config import load_profile
from fluidsense.controller.config.gripper import GripperConfig
from fluidsense.controller.cycles.analysis import CycleResult, Reference, WindowResult, judge_object, object_bound
from fluidsense.controller.cycles.sequencer import State
from fluidsense.controller.requests.dispatch import Dispatcher
from fluidsense.controller.requests.ports import DispatchPort, GripPort, JobPort
from fluidsense.controller.requests.wiring import assemble

from support.harness import PROFILE, REPO

CALIBRATION = REPO / "config" / "calibrations" / "pneunet-gripper-p_eq.json"
BLOCK = 10  # samples per block at 1 kHz, as the simulated cell sends them

# Requests the command socket refuses, and a word of each reason: tests/system/test_zmq.py sends
# them to a daemon, tests/unit/test_requests.py to the socket's decoding and the dispatcher
BAD_REQUESTS = [
    ([b"not json"], "not a JSON object"),
    ([b"[1, 2]"], "must be a JSON object"),
    ([b'{"cmd": "explode"}'], "unknown command"),
    ([b'{"nocmd": 1}'], "unknown command"),
    ([b'{"cmd": "cycle", "p0_kpa": "high"}'], "p0_kpa"),
    ([b'{"cmd": "cycle", "p0_kpa": 5000}'], "p0_kpa"),
    ([b'{"cmd": "status", "extra": 1}'], "extra"),
    ([b'{"cmd": "scene", "scene": {"kind": "dragon"}}'], "scene"),
    ([b"\xff\xfe\x00"], "not a JSON object"),
    ([b'{"cmd": "status"}', b"second frame"], "one frame"),
    ([b'{"cmd": "cycle", "p0_kpa": 95}'], "outside the profile's limits"),
]


@dataclass
class FakeCycle:
    """The cycle as the handlers read it (ports.RunningCycle)."""

    state: State = State.IDLE
    cycle_id: int = 0
    p0_pa: float = 63e3
    t_open: float | None = None

    @property
    def busy(self) -> bool:
        return self.state not in (State.IDLE, State.FAULT)


@dataclass
class FakeCell:
    profile: Any = field(default_factory=lambda: load_profile(PROFILE))
    virtual: bool = True
    connected: bool = True
    connecting: dict[str, Any] | None = None
    t: float = 0.0  # sample time: the newest sample's
    cycle: FakeCycle = field(default_factory=FakeCycle)
    references: dict[float, Reference] = field(default_factory=dict)  # by P0 in Pa
    refuse: Exception | None = None  # what the next start_cycle raises (the controller's own refusal)
    asked: list[tuple] = field(default_factory=list)  # what the handlers asked, in order
    events: list[tuple[str, dict[str, Any]]] = field(default_factory=list)
    _result: asyncio.Future | None = None
    _measured: asyncio.Future | None = None

    # ------------------------------------------------------------------ what the ports do
    async def start_cycle(self, *, p0_kpa: float | None = None, label: str | None = None,
                          store_reference: bool = False, hold: bool = False) -> asyncio.Future:
        self.asked.append(("start_cycle", p0_kpa, store_reference, hold))
        if self.refuse is not None:
            raise self.refuse
        if self.cycle.busy:
            raise SequenceError(f"busy: cycle {self.cycle.cycle_id} is in {self.cycle.state.value}")
        p0 = (self.profile.sequence.p0_kpa if p0_kpa is None else p0_kpa) * KPA
        c = self.cycle  # changed in place, as the sequencer is
        c.state, c.cycle_id, c.p0_pa, c.t_open = State.CHARGE, c.cycle_id + 1, p0, None
        loop = asyncio.get_running_loop()
        self._result, self._measured = loop.create_future(), loop.create_future()
        return self._result

    async def measured_result(self) -> CycleResult:
        return await self._measured

    async def let_go(self) -> None:
        self.asked.append(("let_go",))
        self.cycle.state = State.VENT

    async def abort(self, reason: str) -> bool:
        self.asked.append(("abort", reason))
        if not self.cycle.busy:
            return False
        self.cycle.state = State.VENT
        return True

    async def wait(self, seconds: float) -> None:
        self.asked.append(("wait", seconds))
        self.t += seconds

    async def fail(self, detail: str) -> None:
        self.asked.append(("fail", detail))

    def emit(self, topic: str, payload: dict[str, Any]) -> None:
        self.events.append((topic, payload))

    def reset(self) -> None:
        self.asked.append(("reset",))
        self.cycle.state = State.IDLE

    async def place(self, scene: Any) -> None:
        self.asked.append(("place", scene))

    def status(self) -> dict[str, Any]:
        return {"state": self.cycle.state.value if self.connected else "connecting", "cycle_id": self.cycle.cycle_id,
                "backend": "fake"}

    # ------------------------------------------------------------------ the ports and the handlers on them
    def ports(self) -> tuple[DispatchPort, GripPort, JobPort]:
        now = lambda: self.t  # noqa: E731
        return (DispatchPort(backend="fake", connected=lambda: self.connected, connecting=lambda: self.connecting,
                             cycle=self.cycle, status=self.status, start_cycle=self.start_cycle, abort=self.abort,
                             reset=self.reset, place=self.place, fail=self.fail),
                GripPort(now=now, virtual=self.virtual, cycle=self.cycle, reference=self.references.get,
                         start_cycle=self.start_cycle, measured=self.measured_result, let_go=self.let_go,
                         abort=self.abort, wait=self.wait, fail=self.fail, emit=self.emit),
                JobPort(cycle=self.cycle, abort=self.abort, fail=self.fail, emit=self.emit))

    def requests(self, gripper: GripperConfig | None = None, **kwargs: Any) -> Dispatcher:
        """The dispatcher and its handlers, as the daemon assembles them."""
        return assemble(*self.ports(), gripper or GripperConfig(), self.profile, **kwargs)

    # ------------------------------------------------------------------ the cycle's course, moved by the test
    def open(self) -> None:
        """The actuation valve opens now."""
        self.cycle.state, self.cycle.t_open = State.ACTUATE, self.t

    def measured(self, result: CycleResult) -> None:
        self._measured.set_result(result)

    def hold(self) -> None:
        self.cycle.state = State.HOLD

    def end(self, aborted: str | None = None) -> None:
        """The cycle is over: vented, its final result to whoever waits."""
        self.cycle.state = State.IDLE
        self._result.set_result(self.result(aborted=aborted))
        if not self._measured.done():
            self._measured.set_result(self.result(aborted=aborted))

    def result(self, p_eq_kpa: float | None = None, *, aborted: str | None = None, has_reference: bool = False,
               t_c_s: float | None = None, offset_kpa: float = 0.0) -> CycleResult:
        """The cycle's result as the controller's analysis gives it (SI inside): with a
        reference, dP_eq against the reference's level in the window, and the object judged
        from it and the contact time as analysis.judge_object judges it."""
        window = WindowResult("eq", 4.0, 5.0, p_eq_kpa * KPA, 50.0, 1000) if p_eq_kpa is not None else None
        res = CycleResult(self.cycle.cycle_id, self.cycle.p0_pa, 0.0, self.cycle.t_open, self.t, aborted=aborted,
                          offset=offset_kpa * KPA, windows=[window] if window else [], has_reference=has_reference,
                          t_c_threshold=t_c_s)
        ref = self.references.get(self.cycle.p0_pa)
        if has_reference and window is not None and ref is not None:
            sel = (ref.t_rel >= window.start_s) & (ref.t_rel < window.end_s)
            free = float(ref.p[sel].mean())
            res.dp_eq = window.mean - free
            res.object_bound = object_bound(self.profile.sequence, self.profile.circuit, free, self.cycle.p0_pa)
            res.object, res.object_note = judge_object(res)
        return res

    def feed(self, handler: Any, seconds: float, p_pa: Any) -> None:
        """``seconds`` of samples to ``handler.on_block``, block by block: ``p_pa`` is the
        actuator pressure, a number or a function of the time since the valve opened."""
        t0 = self.t
        for start in range(0, int(round(seconds * 1000)), BLOCK):
            t = t0 + (np.arange(start, start + BLOCK) + 1) / 1000.0
            t_rel = t - (self.cycle.t_open if self.cycle.t_open is not None else np.inf)
            p = p_pa(t_rel) if callable(p_pa) else np.full(BLOCK, float(p_pa))
            self.t = float(t[-1])  # now: the newest sample's time, as the controller's clock
            handler.on_block(SampleBlock(start // BLOCK, t, p.reshape(-1, 1), ("p_act",)))


async def settle() -> None:
    """Let the handlers' own tasks run to where they wait again (no clock involved)."""
    for _ in range(20):
        await asyncio.sleep(0)
