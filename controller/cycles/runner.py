"""The cycle runner: carries out the sequencer's plans on the devices, keeps each cycle's
trace, and turns it into a result (features) when the cycle ends.

The sequencer decides (pure, in sample time); the runner acts: every action goes to its
device, and a device that does not carry one out is a ``command`` fault. A held cycle
stays inflated after its measurement windows until ``release()``; ``measured()`` gives
its features as soon as the last window has closed. Free-air references are kept per P0,
results for the last 100 cycles (features only: a trace is ~0.6 MB).
"""

from __future__ import annotations

import asyncio
import logging
from collections import deque
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from fluidsense.common.errors import NotSupportedError, SafetyError, SequenceError
from fluidsense.common.faults import Fault, FaultKind
from fluidsense.common.samples import SampleBlock
from fluidsense.common.units import KPA
from fluidsense.drivers.backend import Backend

from ..config import Profile
from ..path import Events, Faults, SampleTime
from . import features as F
from .analysis import (
    CycleResult,
    CycleTrace,
    Reference,
    analyse,
    make_reference,
    reference_key,
    transition_dict,
)
from .sequencer import (
    Action,
    FlowProfileAction,
    Sequencer,
    SetpointAction,
    State,
    ValveAction,
)

log = logging.getLogger(__name__)

CHARGE_FLOOR_KPA = 0.05  # the default charge tolerance's least (sequence.charge_tolerance_kpa)


def freeze_for(profile: Profile, freeze_s: float | None) -> float | None:
    """``freeze_s`` where a frozen p_act can be told from a live one: not for a sensor the
    profile declares noise-free and unquantised (the supervisor's stuck check skips it too)."""
    sensor = profile.sensor
    return freeze_s if sensor.noise_sd_kpa > 0 or sensor.quantum_kpa > 0 else None


def _action_dict(action: Action) -> dict[str, Any]:
    if isinstance(action, ValveAction):
        return {"kind": "valve", "valve": action.valve, "open": action.open}
    if isinstance(action, SetpointAction):
        return {"kind": "setpoint", "pressure_pa": action.pressure_pa}
    return {"kind": "flow_profile", "times_s": list(action.times), "flows_m3_s": list(action.flows)}


class CycleRunner:
    def __init__(self, profile: Profile, backend: Backend, *, clock: SampleTime, events: Events, faults: Faults,
                 freeze_s: float | None = None):
        """``clock``: sample time; ``events``: where the cycle's events go (``emit``
        publishes; ``record`` hands one only to the sinks: a cycle's start, each action,
        what a replay needs); ``faults``: the safety latch, where a refused action trips a
        fault; ``freeze_s``: supervision.freeze_s (analysis.analyse)."""
        self.profile, self.backend = profile, backend
        self.freeze_s = freeze_for(profile, freeze_s)
        self._clock, self._events, self._faults = clock, events, faults
        self.sequencer = Sequencer(profile.sequence, backend.valves.safe_positions, settled=self._settled,
                                   charged=self._charged)
        self.references: dict[float, Reference] = {}
        #: called with (p0_pa, key, reference) when a cycle stores a free-air reference
        self.on_reference: list[Callable[[float, float, Reference], None]] = []
        self.results: deque[CycleResult] = deque(maxlen=100)
        self._trace: CycleTrace | None = None
        self._result: asyncio.Future[CycleResult] | None = None
        self._measured: asyncio.Future[CycleResult] | None = None
        self._hold = False
        self._opts: dict[str, Any] = {}

    @property
    def busy(self) -> bool:
        return self.sequencer.busy

    @property
    def holding(self) -> bool:
        """Inflated, measured, waiting: where a leak shows as a steady decay."""
        return self.sequencer.state == State.HOLD and self._measured is not None and self._measured.done()

    @property
    def wants_samples(self) -> bool:
        """A cycle needs samples to go on; a held one whose measurement is done waits on
        its task, not on samples (virtual time: sample time may stand still)."""
        return self.sequencer.busy and not (self._hold and self.holding)

    # ------------------------------------------------------------------ commands
    def check_p0(self, p0: float) -> None:
        lim, margin = self.profile.limits, self.profile.p0_margin_kpa
        if not lim.min_kpa <= p0 <= lim.max_kpa:
            raise SafetyError(f"p0 {p0} kPa outside the profile's limits [{lim.min_kpa}, {lim.max_kpa}] kPa")
        if self.profile.sequence.method != "flow_control" and not lim.min_kpa + margin <= p0 <= lim.max_kpa - margin:
            raise SafetyError(f"p0 {p0} kPa within {margin:.2f} kPa of the profile's limits [{lim.min_kpa}, "
                              f"{lim.max_kpa}] kPa: its readings would cross the limit and fault the cycle")

    async def start(self, p0_kpa: float | None, label: str | None, store_reference: bool,
                    hold: bool) -> asyncio.Future[CycleResult]:
        if self.sequencer.busy:
            raise SequenceError(f"busy: cycle {self.sequencer.cycle_id} is in {self.sequencer.state.value}")
        p0 = self.profile.sequence.p0_kpa if p0_kpa is None else p0_kpa
        self.check_p0(p0)
        actions = self.sequencer.start(self._clock.now, p0 * KPA, hold=hold)
        loop = asyncio.get_running_loop()
        self._opts, self._hold = {"label": label, "store_reference": store_reference}, hold
        self._measured, self._result, self._trace = loop.create_future(), loop.create_future(), CycleTrace()
        self._events.record("cycle_start", {"cycle_id": self.sequencer.cycle_id, "p0_pa": self.sequencer.p0_pa,
                                     "label": label, "store_reference": store_reference, "hold": hold})
        self.publish_transitions()
        await self.apply(actions)
        return self._result

    async def measured(self) -> CycleResult:
        if self._measured is None:
            raise SequenceError("no cycle is running")
        return await self._measured

    async def release(self) -> CycleResult:
        return await (await self.let_go())

    async def let_go(self) -> asyncio.Future[CycleResult]:
        """A held cycle vents (``release`` without waiting): the future of its result."""
        fut = self._result
        if fut is None or not self.sequencer.busy:
            raise SequenceError("no cycle is running")
        actions = self.sequencer.release(self._clock.now)
        self.publish_transitions()
        await self.apply(actions)
        return fut

    async def abort(self, reason: str) -> bool:
        if not self.sequencer.busy:
            return False
        actions = self.sequencer.abort(self._clock.now, reason)
        self.publish_transitions()
        await self.apply(actions)
        return True

    def reset(self) -> None:
        self.sequencer.reset(self._clock.now)
        self.publish_transitions()

    # ------------------------------------------------------------------ the loop's side
    def trace(self, block: SampleBlock) -> None:
        """The block's samples into the running cycle's trace (before anything acts on
        them: a block that faults a cycle belongs to it)."""
        if self._trace is not None:
            self._trace.add(block)

    async def on_block(self) -> None:
        """The actions due now; the features once the windows have closed; the result once
        the cycle is over."""
        actions = self.sequencer.on_time(self._clock.now)
        if actions:
            await self.apply(actions)
        self.publish_transitions()
        if self._measured is not None and not self._measured.done() and self._measurement_due():
            self._measured.set_result(self._analyse(final=False))
        if self.sequencer.state == State.IDLE and self._trace is not None:
            self.finish()

    def on_fault(self, fault: Fault) -> None:
        """The latch's first word: the sequence stops commanding (every valve goes safe)."""
        self.sequencer.fault(self._clock.now, f"fault: {fault.kind}")

    def after_fault(self, fault: Fault, event: dict[str, Any]) -> None:
        """The cycle ends with what it measured; its waiters get an aborted result."""
        self.publish_transitions()
        if self._trace is not None:
            self.finish()

    async def apply(self, actions: list[Action]) -> None:
        """Each action to its device; one that is refused or fails is a command fault."""
        try:
            for action in actions:
                await self._act(action)
                self._events.record("command", _action_dict(action))
        except Exception as exc:  # noqa: BLE001
            log.error("command failed: %s", exc)
            await self._faults.trip(Fault(FaultKind.COMMAND, None, self._clock.now, str(exc)), self._clock.now)

    async def _act(self, action: Action) -> None:
        now = self._clock.now
        if isinstance(action, ValveAction):
            await self.backend.valves.set(action.valve, action.open, now)
        elif isinstance(action, SetpointAction):
            if self.backend.regulator is None:
                raise NotSupportedError("this cell has no pressure regulator")
            await self.backend.regulator.set_setpoint(action.pressure_pa, now)
        elif isinstance(action, FlowProfileAction):
            if self.backend.flow is None:
                raise NotSupportedError("this cell has no flow controller")
            if action.times:
                await self.backend.flow.set_profile(action.times, action.flows, now)
            else:
                await self.backend.flow.stop_flow(now)

    def publish_transitions(self) -> None:
        for tr in self.sequencer.drain_transitions():
            self._events.emit("state", transition_dict(tr))

    def _settled(self, t_now: float) -> str | None:
        """None when the vented actuator has read flat over the last ``settle_s``
        (its drift within 2 standard errors of the noise, or below the floor), else why
        not. The runner holds the cycle's samples, so it is the one to look."""
        cfg = self.profile.sequence
        if self._trace is None:
            return None
        window = cfg.settle_s
        t, values = self._trace.tail(window)
        if len(t) < 3 or t[0] > t_now - window + 1.5 * (t[1] - t[0]):
            return f"fewer than {window:g} s of vented readings yet"
        sel = t > t_now - window
        change, se = F.drift(t[sel], values[sel, self._trace.channels.index("p_act")])
        limit = max(2.0 * se, cfg.settle_floor_kpa * KPA)
        if abs(change) <= limit:
            return None
        return (f"the vented actuator still moves {change / KPA:+.4f} kPa over {window:g} s "
                f"(flat is within {limit / KPA:.4f} kPa)")

    def _charged(self, t_now: float) -> str | None:
        """None when the tank (tank method) or the regulated buffer (pressure_flow) has read
        P0 within ``charge_tolerance_kpa`` over the last ``offset_s``, else what it read.
        Without a tank sensor (flow control) there is nothing to check."""
        cfg, seq = self.profile.sequence, self.sequencer
        if self._trace is None or "p_tank" not in self._trace.channels:
            return None
        t, values = self._trace.tail(cfg.offset_s)
        sel = t > t_now - cfg.offset_s
        if not sel.any():
            return f"no tank reading in the last {cfg.offset_s:g} s"
        p_tank = float(values[sel, self._trace.channels.index("p_tank")].mean())
        # at least CHARGE_FLOOR_KPA: a profile that declares its sensor and regulator ideal
        # has a margin of 0, which a tank approaching P0 exponentially would never meet
        tol = (cfg.charge_tolerance_kpa or max(self.profile.p0_margin_kpa, CHARGE_FLOOR_KPA)) * KPA
        if abs(p_tank - seq.p0_pa) <= tol:
            return None
        what = "tank" if cfg.method == "tank" else "regulated buffer"
        return (f"the {what} reads {p_tank / KPA:.2f} kPa, P0 is {seq.p0_pa / KPA:.2f} kPa "
                f"(within {tol / KPA:.2f} kPa expected): the reading would be wrong (the supply below P0, "
                "the regulator, a leak from the tank, the tank sensor?)")

    def _measurement_due(self) -> bool:
        seq = self.sequencer
        if seq.t_open is None:
            return seq.aborted is not None or not seq.busy
        last = max(w.end_s for w in self.profile.sequence.windows)
        return self._clock.now >= seq.t_open + last or seq.aborted is not None or not seq.busy

    def _analyse(self, final: bool) -> CycleResult:
        trace, seq, now = self._trace, self.sequencer, self._clock.now
        t, values = trace.arrays()
        ref = None if self._opts.get("store_reference") else self.references.get(reference_key(seq.p0_pa))
        try:
            return analyse(seq.cycle_id, seq.p0_pa, seq.t_start, seq.t_open, (seq.t_end or now) if final else None,
                           t, values, trace.channels, self.profile.sequence, ref, aborted=seq.aborted,
                           label=self._opts.get("label"), missed=trace.missed, circuit=self.profile.circuit,
                           freeze_s=self.freeze_s)
        except ValueError as exc:  # too few samples for a window: report, do not crash
            return CycleResult(seq.cycle_id, seq.p0_pa, seq.t_start, seq.t_open, now,
                               aborted=f"analysis failed: {exc}", missed=trace.missed)

    def finish(self) -> None:
        """The cycle is over (done, aborted, faulted, or the controller stops): its result."""
        result = self._analyse(final=True)
        self._trace = None
        if self._measured is not None and not self._measured.done():
            self._measured.set_result(result)
        if self._opts.get("store_reference") and result.ok:
            key, ref = reference_key(self.sequencer.p0_pa), make_reference(result)
            self.references[key] = ref
            result.is_reference = True
            for stored in self.on_reference:
                stored(self.sequencer.p0_pa, key, ref)
        self.results.append(replace(result, trace=None))
        self._events.emit("cycle", result.to_dict())
        fut, self._result = self._result, None
        if fut is not None and not fut.done():
            fut.set_result(result)

    @property
    def tracing(self) -> bool:
        """A cycle is collecting samples (it has not been turned into a result yet)."""
        return self._trace is not None

    def fail(self, exc: BaseException) -> None:
        """The controller stops: whoever waits on the cycle gets ``exc``."""
        for fut in (self._result, self._measured):
            if fut is not None and not fut.done():
                fut.set_exception(exc)
