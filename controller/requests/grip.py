"""The gripper's requests: ``grip`` (close and stay holding), ``release`` (vent, then
ready) and ``measure`` (one sensing cycle), and the live events of a grip.

A grip is a held cycle (charge -> isolate -> actuate -> hold until released); a measure
is an ordinary cycle. Both go through the controller's cycle runner, so the safety latch,
the supervisor (limits, leak while held) and ``abort`` apply to them as to any cycle.
Events, on their own topics (docs/zmq-schema.md):

    contact   first contact during actuation (needs a free-air reference at that P0)
    grasp     the measurement windows closed: object or not, estimates in mm
    slip      while held, an abrupt fall of the pressure, with the size after it
    released  the cycle is over and the gripper open (why: release, abort, fault, ...)

Requests reply at once (the socket answers one request at a time: a reply that waited for
the grasp would keep ``abort`` out); the client library waits for the events. The handler
reads and asks the controller through its port (ports.GripPort) and nothing else. It
follows a cycle it started through the cycle's futures (the features, then the end: done
callbacks, no task of its own) and block by block as one of the controller's block
watchers (controller/path.py BlockWatcher: ``on_block``, wired by wiring.py).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from functools import partial
from types import SimpleNamespace
from typing import Any, Literal

from fluidsense.common.errors import FluidsenseError, SafetyError, SequenceError
from fluidsense.common.models import StrictModel
from fluidsense.common.samples import SampleBlock
from fluidsense.common.units import KPA
from pydantic import Field

from ..config import Profile
from ..config.gripper import GripperConfig
from ..cycles.analysis import CycleResult, alignment, object_bound
from ..cycles.sequencer import State
from . import estimates as E
from .grip_watch import ContactWatch, SlipWatch
from .ports import GripPort
from .routing import answers

log = logging.getLogger(__name__)

#: the cycle's features a grasp carries beside its estimates, as the cycle's result
#: publishes them (CycleResult.to_dict: the unit in each name)
GRASP_FEATURES = ("p_eq_kpa", "p_sd_kpa", "offset_kpa", "dp_eq_kpa", "dp_max_kpa", "t_c_slope_s", "t_c_threshold_s",
                  "rise_shift_s", "object_bound_kpa",
                  "v_eq_ml")


class GripRequest(StrictModel):
    """Close and stay holding; ``timeout_s``: sample time to the grasp before the grip is
    given up (vented)."""

    cmd: Literal["grip"]
    p0_kpa: float | None = Field(None, ge=-101, le=1000)
    timeout_s: float | None = Field(None, gt=0, le=3600)
    label: str | None = Field(None, max_length=80)


class ReleaseRequest(StrictModel):
    cmd: Literal["release"]


class MeasureRequest(StrictModel):
    cmd: Literal["measure"]
    p0_kpa: float | None = Field(None, ge=-101, le=1000)
    label: str | None = Field(None, max_length=80)
    store_reference: bool = False


class GripHandler:
    """The gripper's requests, and the watch over every block of a grip (a block watcher:
    controller/path.py BlockWatcher)."""

    def __init__(self, port: GripPort, cfg: GripperConfig, profile: Profile,
                 running_task: Callable[[], str | None] = lambda: None):
        """``running_task``: the file of the task that runs, if one does (none may start a grip)."""
        self.port, self.cfg, self.plan, self._running_task = port, cfg, profile.sequence, running_task
        self._circuit = profile.circuit
        self.calibrations = [E.load_calibration(p, profile.name, f"gripper.calibrations.{i}")
                             for i, p in enumerate(cfg.calibrations)]
        self.op: str | None = None  # "grip" or "measure" while one runs
        self.cycle_id: int | None = None
        self.last_grasp: dict[str, Any] | None = None
        self.t_grasp: float | None = None
        self._deadline = float("inf")
        self._reason: str | None = None  # why the gripper opens, when it was the gripper's choice
        self._contact: ContactWatch | None = None
        self._sign = 1.0
        self._offset = 0.0
        self._t_opened: float | None = None  # a held grip left HOLD (released, aborted, faulted)
        self._slip: SlipWatch | None = None
        self._storing_reference = False  # the cycle that runs measures the free-air reference

    # ------------------------------------------------------------------ state
    @property
    def holding(self) -> bool:
        """A grip has closed on its measurement and stays closed."""
        return self.op == "grip" and self.t_grasp is not None

    @property
    def object(self) -> bool | None:
        return None if not self.holding or self.last_grasp is None else self.last_grasp["object"]

    def status(self) -> dict[str, Any]:
        return {"holding": self.holding, "object": self.object, "gripper_op": self.op,
                "calibrated": bool(self.calibrations), "last_grasp": self.last_grasp}

    # ------------------------------------------------------------------ requests
    @answers(GripRequest)
    async def grip(self, req: GripRequest) -> dict[str, Any]:
        self._check_free("grip")
        plan = self.plan
        needed = plan.charge_s + plan.isolate_s + max(w.end_s for w in plan.windows)
        if req.timeout_s is not None and req.timeout_s < needed:
            raise SafetyError(f"timeout_s {req.timeout_s:g} is shorter than this profile's grip: {needed:g} s of "
                              f"sample time from charge to the end of the measurement windows")
        return await self._start("grip", req.p0_kpa, req.label, False, hold=True, timeout_s=req.timeout_s)

    @answers(ReleaseRequest)
    async def release(self, req: ReleaseRequest | None = None) -> dict[str, Any]:
        cycle = self.port.cycle
        if self.op is None:
            if cycle.busy:
                raise SequenceError(f"cycle {cycle.cycle_id} is not a grip: send abort to stop it")
            raise SequenceError("nothing to release: the gripper is open")
        if self.op == "measure":
            raise SequenceError(f"cycle {self.cycle_id} is a measure: it vents by itself (send abort to stop it now)")
        if cycle.state == State.VENT:
            return {"cycle_id": self.cycle_id, "releasing": True, "state": cycle.state.value}
        self._reason = self._reason or "release"
        if cycle.state in (State.ACTUATE, State.HOLD):
            await self.port.let_go()
        else:  # still charging: nothing closed yet, opening is aborting
            await self.port.abort("released before actuation")
        return {"cycle_id": self.cycle_id, "releasing": True, "state": cycle.state.value}

    @answers(MeasureRequest)
    async def measure(self, req: MeasureRequest) -> dict[str, Any]:
        self._check_free("measure")
        return await self._start("measure", req.p0_kpa, req.label, req.store_reference, hold=False, timeout_s=None)

    async def after_scene(self) -> None:
        """A scene changed under a held grip. In virtual time sample time stands still while
        holding: run it a little so the grip sees the change, as it would in real time."""
        if self.holding and self.port.virtual and self.cfg.settle_s > 0:
            await self.port.wait(self.cfg.settle_s)

    def _check_free(self, what: str) -> None:
        cycle, task = self.port.cycle, self._running_task()
        if self.holding:
            raise SequenceError(f"holding (cycle {self.cycle_id}): send release before {what}")
        if task is not None:
            raise SequenceError(f"busy: task {task} is running")
        if cycle.busy:
            raise SequenceError(f"busy: cycle {cycle.cycle_id} is in {cycle.state.value}")

    async def _start(self, op: str, p0_kpa: float | None, label: str | None, store_reference: bool, *, hold: bool,
                     timeout_s: float | None) -> dict[str, Any]:
        port, plan = self.port, self.plan
        fut = await port.start_cycle(p0_kpa=p0_kpa, label=label, store_reference=store_reference, hold=hold)
        cycle = port.cycle
        self.op, self.cycle_id, self.t_grasp, self._reason = op, cycle.cycle_id, None, None
        self._storing_reference = store_reference
        self._deadline = float("inf") if timeout_s is None else port.now() + timeout_s
        self._sign = -1.0 if cycle.p0_pa < 0 else 1.0
        reference = None if store_reference else port.reference(cycle.p0_pa)
        align = None if reference is None else alignment(plan, reference, self._sign)
        self._contact = ContactWatch(reference, plan.contact_threshold_kpa * KPA, self._sign, plan.offset_s,
                                     max(w.end_s for w in plan.windows), align)
        self._slip = None
        measured = asyncio.ensure_future(port.measured())
        measured.add_done_callback(partial(self._on_measured, fut))
        return {"cycle_id": cycle.cycle_id, "p0_kpa": cycle.p0_pa / KPA, "reference": reference is not None}

    # ------------------------------------------------------------------ the cycle's course
    def _on_measured(self, done: asyncio.Future[CycleResult], measured: asyncio.Future[CycleResult]) -> None:
        """The cycle's features are in (its windows closed): the grasp; then its end."""
        if measured.cancelled() or not self._follow(self._measured, measured):
            return
        if done.done():  # as awaiting a finished future would: at once
            self._on_done(done)
        else:
            done.add_done_callback(self._on_done)

    def _on_done(self, done: asyncio.Future[CycleResult]) -> None:
        """The cycle is over: the gripper is open."""
        if not done.cancelled():
            self._follow(self._released, done)

    def _follow(self, step: Callable[[CycleResult], None], fut: asyncio.Future[CycleResult]) -> bool:
        """``step`` on the future's result; False when the course ends here instead."""
        try:
            step(fut.result())
            return True
        except FluidsenseError:  # the controller stopped under the cycle: nothing to report
            self.op = None
        except Exception as exc:  # noqa: BLE001 - a bug here must not leave the gripper closed
            log.exception("following %s %s failed", self.op, self.cycle_id)
            self.op = None
            self._spawn(self.port.fail(f"gripper: {type(exc).__name__}: {exc}"))
        return False

    def _measured(self, res: CycleResult) -> None:
        if res.ok and res.cycle_id == self.cycle_id:
            self._grasp(res)

    def _grasp(self, res: CycleResult) -> None:
        # a measure that stored the free-air reference was asked for with nothing in the
        # gripper: that is what it reports, never a size (its reading is the free level)
        # contact: None where it cannot be told (no reference, or a rise that could not be
        # lined up with the reference's: dP on it would be the valve's timing)
        unaligned = res.t_c_min is not None and res.rise_shift is None
        contact = False if self._storing_reference else None if not res.has_reference or unaligned else \
            res.t_c_threshold is not None
        ests = E.of_result(self.calibrations, res)
        # object: the cycle's judgement (analysis.judge_object: the equilibrium dP and the
        # contact time must agree); without a reference, what the calibrations say of the level
        obj = False if self._storing_reference else res.object if res.has_reference else False if any(
            e["status"] == "no_object" for e in ests) else None
        if obj is False:
            ests = [E.no_object(e) for e in ests]
        ok = [e["status"] == "ok" for e in ests]
        note = None
        if self._storing_reference:
            note = "free-air reference stored at this P0: nothing in the gripper, as asked"
        elif not res.has_reference:
            note = "no free-air reference at this P0: contact and object cannot be told (measure with " \
                   "store_reference and nothing in the gripper; status.reference_store says why a kept one " \
                   "was refused)"
        elif res.object_note:
            note = res.object_note
        if not self.calibrations:
            note = (note + "; " if note else "") + "no calibration loaded: features in kPa only"
        published = res.to_dict()
        self.t_grasp = self.port.now()
        self.last_grasp = {
            "cycle_id": res.cycle_id, "command": self.op, "at_s": self.t_grasp, "p0_kpa": published["p0_kpa"],
            "object": obj, "contact": contact, "t_c_s": res.t_c_threshold,
            "calibrated": bool(self.calibrations), "estimates": [E.to_edge(e) for e in ests],
            "in_range": None if not ests or obj is False else all(ok), "note": note, "unreliable": res.unreliable,
            "features": {name: published[name] for name in GRASP_FEATURES}}
        self._offset = res.offset or 0.0
        level = (res.p_eq or 0.0) + self._offset
        self._slip = SlipWatch(self.cfg.slip_drop_kpa * KPA, self.cfg.slip_within_s, self._sign, level) \
            if self.op == "grip" else None
        self.port.emit("grasp", self.last_grasp)

    def _released(self, final: CycleResult) -> None:
        reason = self._reason or final.aborted or ("done" if self.op == "measure" else "release")
        now = self.port.now()
        held = None if self.t_grasp is None or self.op != "grip" else (self._t_opened or now) - self.t_grasp
        self.port.emit("released", {"cycle_id": final.cycle_id, "command": self.op, "at_s": now,
                                    "reason": reason, "held_s": held, "ok": final.aborted is None})
        self.op, self.t_grasp, self._slip, self._contact, self._t_opened = None, None, None, None, None

    # ------------------------------------------------------------------ the samples (a block watcher)
    def on_block(self, block: SampleBlock) -> None:
        """A block of samples, after its telemetry (controller/path.py BlockWatcher): a
        grip's contact, its timeout, a slip while held, max_hold_s."""
        if self.op is None or "p_act" not in block.channels:
            return
        port, seq = self.port, self.port.cycle
        now = port.now()
        p = block.channel("p_act")
        if self.t_grasp is not None and self._t_opened is None and seq.state != State.HOLD:
            self._t_opened = float(block.t[0])
        if self._contact is not None and not self._contact.done:
            t_c = self._contact.feed(block.t, p, seq.t_open)
            if t_c is not None:
                port.emit("contact", {"cycle_id": self.cycle_id, "command": self.op, "at_s": seq.t_open + t_c,
                                      "t_c_s": t_c})
        if self.t_grasp is None and now > self._deadline and seq.busy and self._reason is None:
            self._reason = "timeout"
            self._spawn(port.abort("grip timeout"))
        if self._slip is not None and seq.state == State.HOLD:
            slip = self._slip.feed(float(block.t.mean()), float(p.mean()))
            if slip is not None:
                self._slipped(slip)
            if self.holding and now - self.t_grasp > self.cfg.max_hold_s and self._reason is None:
                self._reason = "max_hold_s"
                log.warning("grip %s held for max_hold_s = %g s: releasing", self.cycle_id, self.cfg.max_hold_s)
                self._spawn(self.release())

    def _slipped(self, slip: dict[str, float]) -> None:
        level = slip["level_pa"] - self._offset
        ests = E.of_result(self.calibrations, SimpleNamespace(p_eq=level))
        obj = None
        if self._contact is not None and self._contact.reference is not None:
            ref = self._contact.reference
            first = self.plan.windows[0]
            sel = (ref.t_rel >= first.start_s) & (ref.t_rel < first.end_s)
            free = float(ref.p[sel].mean())
            bound = object_bound(self.plan, self._circuit, free, self.port.cycle.p0_pa)
            obj = bool(self._sign * (level - free) > bound)
            if not obj:
                ests = [E.no_object(e) for e in ests]
        if self.last_grasp is not None:
            self.last_grasp = {**self.last_grasp, "object": obj if obj is not None else self.last_grasp["object"]}
        self.port.emit("slip", {"cycle_id": self.cycle_id, "at_s": slip["at_s"], "held_s": slip["at_s"] - self.t_grasp,
                                "drop_kpa": slip["drop_pa"] / KPA, "p_kpa": level / KPA, "object": obj,
                                "estimates": [E.to_edge(e) for e in ests]})

    def _spawn(self, coro) -> None:
        task = asyncio.get_running_loop().create_task(coro)
        task.add_done_callback(lambda t: t.cancelled() or t.exception() is None
                               or log.error("gripper: %s", t.exception()))


__all__ = ["GripHandler", "GripRequest", "MeasureRequest", "ReleaseRequest"]
