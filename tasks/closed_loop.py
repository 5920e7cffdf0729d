"""The paper's closed-loop experiments as tasks: sorting, tomato picking, ripeness.

Each task drives the arm and the gripper through the controller's task port only
(controller/ports.py TaskPort), takes its
decisions from the fluidic features, publishes its progress (``report``) and returns a
JSON-ready summary. On a simulated cell, where the truth is known, the summary also
scores itself against it.
"""

from __future__ import annotations

import random
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from fluidsense.common.errors import FluidsenseError
from fluidsense.common.units import KPA
from fluidsense.common.world import WorldObject, WorldSlot, WorldSpec
from fluidsense.controller.cycles.analysis import CycleResult
from fluidsense.controller.ports import TaskPort
from fluidsense.controller.sensing.calibration import Calibration, feature_value

from .config import PickingTask, RipenessTask, SortingTask

Report = Callable[[dict[str, Any]], None]


class Cell:
    """Arm and gripper moves in the task's terms: slots, approach heights, grips."""

    def __init__(self, port: TaskPort, task, report: Report):
        self.port, self.task, self.report = port, task, report
        m = task.motion
        self.speed, self.acc, self.up = m.speed_m_s, m.acc_m_s2, m.approach_m

    @property
    def simulated(self) -> bool:
        return self.port.simulated

    async def move(self, pose) -> None:
        await self.port.move_l(pose, self.speed, self.acc)

    def _above(self, pose, dz: float | None = None):
        p = list(pose)
        p[2] += self.up if dz is None else dz
        return p

    async def go_to(self, slot: str) -> None:
        """Lift, travel above the slot, descend onto it."""
        here = self.port.tcp_pose()
        target = self.task.slots[slot]
        await self.move(self._above(here))
        await self.move(self._above(target))
        await self.move(target)

    async def lift(self, dz: float | None = None) -> None:
        await self.move(self._above(self.port.tcp_pose(), dz))

    async def grip(self, p0_kpa: float | None = None, label: str | None = None) -> CycleResult:
        """Close on whatever is at the tool and measure; the gripper stays closed."""
        await self.port.start_cycle(p0_kpa=p0_kpa, label=label, hold=True)
        res = await self.port.measured()
        if res.aborted:
            raise FluidsenseError(f"grip cycle {res.cycle_id} failed: {res.aborted}")
        return res

    async def release(self) -> None:
        await self.port.release()


async def _truth(port: TaskPort) -> dict[str, Any] | None:
    truth = await port.truth()
    return None if truth is None else truth.get("world")


def _timing(port: TaskPort, t0_sample: float, t0_wall: float) -> dict[str, float]:
    return {"duration_s": port.now() - t0_sample, "wall_s": time.perf_counter() - t0_wall}


# ---------------------------------------------------------------------- sorting
async def sorting(port: TaskPort, task: SortingTask, report: Report, order_mm: list[float] | None = None) -> dict:
    """Modified insertion sort into a separate sorted array (paper, "Sorting experiment"):
    each new object is gripped and measured; the sorted array holds the largest P_eq
    first; a new object smaller than all goes to the end, otherwise the objects after its
    place are shifted one slot along first."""
    cell = Cell(port, task, report)
    order = order_mm if order_mm is not None else task.order_mm
    names: dict[str, str] = {}
    if cell.simulated:
        if order is None:
            raise FluidsenseError("a simulated sorting run needs order_mm (or --order)")
        objects = [WorldObject(name=f"D{d:g}-{i}", diameter_mm=d, offset_mm=task.object_offset_mm)
                   for i, d in enumerate(order)]
        slots = [WorldSlot(name=s, pose=task.slots[s], object=objects[i].name if i < len(objects) else None)
                 for i, s in enumerate(task.input_slots)]
        slots += [WorldSlot(name=s, pose=task.slots[s]) for s in task.sorted_slots]
        await port.lay_out(WorldSpec(slots=slots, objects=objects))
        names = {o.name: o.diameter_mm for o in objects}
    t0, w0 = port.now(), time.perf_counter()
    sorted_vals: list[float] = []  # P_eq (kPa) of the objects in sorted_slots, largest first
    readings = []
    n_inputs = len(order) if order is not None else len(task.input_slots)
    for i, slot in enumerate(task.input_slots[:n_inputs]):
        await cell.go_to(slot)
        res = await cell.grip(label=f"measure {slot}")
        v = res.p_eq / KPA
        readings.append({"slot": slot, "p_eq_kpa": v, "p_sd_kpa": res.p_sd / KPA})
        k = next((j for j, s in enumerate(sorted_vals) if v > s), len(sorted_vals))
        report({"event": "measured", "slot": slot, "p_eq_kpa": v, "position": k})
        if k < len(sorted_vals):
            await cell.release()  # put it back and make room first
            for j in range(len(sorted_vals) - 1, k - 1, -1):
                await cell.go_to(task.sorted_slots[j])
                await cell.grip(label=f"shift {task.sorted_slots[j]}")
                await cell.go_to(task.sorted_slots[j + 1])
                await cell.release()
                report({"event": "shifted", "from": task.sorted_slots[j], "to": task.sorted_slots[j + 1]})
            await cell.go_to(slot)
            await cell.grip(label=f"take {slot}")
        await cell.go_to(task.sorted_slots[k])
        await cell.release()
        sorted_vals.insert(k, v)
        report({"event": "placed", "slot": slot, "to": task.sorted_slots[k], "sorted_kpa": list(sorted_vals)})
    await cell.lift()
    summary: dict[str, Any] = {"task": "sorting", "readings": readings, "sorted_p_eq_kpa": sorted_vals,
                               **_timing(port, t0, w0)}
    world = await _truth(port)
    if world is not None:
        final = [names.get(world["content"][s]) for s in task.sorted_slots[:n_inputs]]
        summary["final_order_mm"] = final
        summary["input_order_mm"] = list(order)
        summary["success"] = None not in final and final == sorted(final, reverse=True)
    return summary


# ----------------------------------------------------------------- tomato picking
async def picking(port: TaskPort, task: PickingTask, report: Report) -> dict:
    """Reference grips in free air at each P0, then per tomato: grip, turn and retract,
    measure; picked when dP = P_eq - P_ref exceeds the threshold, else drop and try the
    next P0 (paper, "Tomato picking experiment"). A drop between the early window and
    the measurement window is reported as a slip."""
    cell = Cell(port, task, report)
    if cell.simulated:
        tomatoes = task.tomatoes or [None] * len(task.tomato_slots)
        objects = [WorldObject(name=f"tomato{i + 1}", **(t.model_dump() if t else {"diameter_mm": 60.0}))
                   for i, t in enumerate(tomatoes)]
        slots = [WorldSlot(name=s, pose=task.slots[s], object=objects[i].name)
                 for i, s in enumerate(task.tomato_slots)]
        slots += [WorldSlot(name=s, pose=task.slots[s]) for s in task.place_slots]
        await port.lay_out(WorldSpec(slots=slots, objects=objects))
    t0, w0 = port.now(), time.perf_counter()
    refs: dict[float, float] = {}
    if task.home is not None:
        await cell.move(task.home)
    for p0 in task.p0_steps_kpa:  # the gripper closes in the air without moving
        await cell.grip(p0_kpa=p0, label=f"reference {p0:g}")
        res = await port.release()
        refs[p0] = res.p_eq / KPA
        report({"event": "reference", "p0_kpa": p0, "p_eq_kpa": refs[p0]})
    outcomes = []
    for i, slot in enumerate(task.tomato_slots):
        attempts, decision = [], "not_picked"
        for p0 in task.p0_steps_kpa:
            await cell.go_to(slot)
            await port.start_cycle(p0_kpa=p0, label=f"pick {slot} at {p0:g}", hold=True)
            await port.wait_after_open(task.retract_after_s)
            await cell.lift(task.retract_m)  # turn the tomato off the stem and retract
            res = await port.measured()
            w = {x.name: x.mean / KPA - refs[p0] for x in res.windows}
            dp, dp_early, dp_carried = w["eq"], w.get("early", w["eq"]), w.get("carried", w["eq"])
            picked = dp > task.dp_threshold_kpa
            # held after the retract, then an abrupt drop while carried: slipped into the
            # palm (a tomato left on the stem drops the pressure at the retract instead)
            slip = (not picked and dp_carried > task.dp_threshold_kpa
                    and dp_carried - dp > task.slip_drop_kpa)
            left = dp_early > task.dp_threshold_kpa and dp_carried <= task.dp_threshold_kpa
            attempts.append({"p0_kpa": p0, "dp_kpa": dp, "dp_early_kpa": dp_early, "dp_carried_kpa": dp_carried,
                             "slip_detected": slip, "left_on_stem": left, "picked": picked})
            report({"event": "attempt", "slot": slot, **attempts[-1]})
            if picked:
                await cell.go_to(task.place_slots[i])
                await cell.release()
                decision = "picked"
                break
            await cell.release()  # not recognised: drop whatever is in the palm, try harder
            if slip:
                decision = "slipped"
        outcomes.append({"slot": slot, "decision": decision, "attempts": attempts})
        report({"event": "tomato", "slot": slot, "decision": decision})
    summary: dict[str, Any] = {"task": "picking", "references_kpa": refs, "tomatoes": outcomes,
                               **_timing(port, t0, w0)}
    world = await _truth(port)
    if world is not None:
        events = world["events"]
        for i, out in enumerate(outcomes):
            name = f"tomato{i + 1}"
            was_picked = any(e["event"] == "picked" and e["object"] == name for e in events)
            placed = world["content"].get(task.place_slots[i]) == name
            out["truth"] = {"picked_off_stem": was_picked, "placed": placed,
                            "slipped": any(e["event"] == "slipped" and e["object"] == name for e in events)}
            out["outcome"] = ("picked_recognised" if placed and out["decision"] == "picked"
                              else "picked_missed" if was_picked else "not_picked")
        summary["counts"] = {k: sum(o["outcome"] == k for o in outcomes)
                             for k in ("picked_recognised", "picked_missed", "not_picked")}
    return summary


# ---------------------------------------------------------------------- ripeness
_D0_FEATURE = {"t_c_threshold": "t_c_threshold", "t_c_onset": "t_c_onset", "t_c_slope": "t_c_slope",
               "dp_max": "dp_max"}


async def ripeness(port: TaskPort, task: RipenessTask, report: Report) -> dict:
    """Calibrate D against t_c (or dP_max) and dP_eq on rigid dummies, then in each round
    grip every object and flag as overripe the one whose size at contact (D0) exceeds its
    size at equilibrium (D1) by more than the threshold (paper, "Tomato ripeness")."""
    cell = Cell(port, task, report)
    rng = random.Random(task.shuffle_seed)
    feat0 = _D0_FEATURE[task.d0_from]
    dummies = [WorldObject(name=f"dummy{d:g}", diameter_mm=d, offset_mm=task.misalignment_mm)
               for d in task.dummy_diameters_mm]
    objects = [WorldObject(name=o.name, diameter_mm=o.diameter_mm, stiffness_n_per_mm=o.stiffness_n_per_mm,
                           relaxed_stiffness_n_per_mm=o.relaxed_stiffness_n_per_mm, creep_s=o.creep_s, ripe=o.ripe)
               for o in task.objects]

    def layout(order: list[WorldObject], offsets: list[float]) -> WorldSpec:
        slots = [WorldSlot(name=s, pose=task.slots[s], object=d.name) for s, d in zip(task.dummy_slots, dummies)]
        placed = [o.model_copy(update={"offset_mm": off}) for o, off in zip(order, offsets)]
        slots += [WorldSlot(name=s, pose=task.slots[s], object=o.name) for s, o in zip(task.object_slots, placed)]
        return WorldSpec(slots=slots, objects=dummies + placed)

    t0, w0 = port.now(), time.perf_counter()

    async def reference() -> None:
        if task.home is not None:
            await cell.move(task.home)
        else:
            await cell.lift()
        await port.start_cycle(label="reference", store_reference=True)
        await port.measured()
        await port.release()

    async def grip_once(slot: str, label: str) -> CycleResult:
        await cell.go_to(slot)
        res = await cell.grip(label=label)
        await cell.release()
        return res

    # calibration round: first grip on each dummy aligns it, the rest calibrate
    if cell.simulated:
        await port.lay_out(layout(objects, [0.0] * len(objects)))
    await reference()
    xs, y0, y1 = [], [], []
    for slot, d in zip(task.dummy_slots, task.dummy_diameters_mm):
        for k in range(task.calibration_grips):
            res = await grip_once(slot, f"calibrate {d:g} mm")
            if k == 0:
                continue
            f0, f1 = feature_value(res, feat0), feature_value(res, "dp_eq")
            if f0 is not None and f1 is not None:
                xs.append(d)
                y0.append(f0)
                y1.append(f1)
    profile = port.profile
    meta = dict(profile=profile.name, method="tank", feature_unit="", scene={}, target="diameter_mm",
                target_unit="mm")
    cal0 = Calibration.fit_points(xs, y0, "poly2" if feat0.startswith("t_c") else "linear", feature=feat0, **meta)
    cal1 = Calibration.fit_points(xs, y1, "linear", feature="dp_eq", **meta)
    report({"event": "calibrated", "d0_from": feat0, "points": len(xs)})
    rounds = []
    for r in range(task.rounds):
        order = list(objects)
        rng.shuffle(order)
        offsets = [rng.uniform(0, task.misalignment_mm) for _ in order]
        if cell.simulated:
            await port.lay_out(layout(order, offsets))
        await reference()
        per_object = []
        for slot, obj in zip(task.object_slots, order):
            if task.centering_grip:
                await grip_once(slot, f"centre {obj.name}")
            diffs = []
            for g in range(task.grips_per_object):
                res = await grip_once(slot, f"round {r + 1} {obj.name}")
                f0, f1 = feature_value(res, feat0), feature_value(res, "dp_eq")
                if f0 is None or f1 is None:
                    diffs.append(float("nan"))
                    continue
                try:
                    d0, d1 = cal0.invert(f0).estimate, cal1.invert(f1).estimate
                except FluidsenseError:
                    diffs.append(float("nan"))
                    continue
                diffs.append(d0 - d1)
            mean = float(np.nanmean(diffs)) if np.isfinite(diffs).any() else float("nan")
            flagged = bool(np.isfinite(mean) and mean > task.threshold_mm)
            per_object.append({"object": obj.name, "slot": slot, "d0_minus_d1_mm": diffs, "mean_mm": mean,
                               "overripe": flagged, "truth_ripe": obj.ripe})
            report({"event": "sensed", "round": r + 1, "object": obj.name, "mean_mm": mean, "overripe": flagged})
        truth_overripe = {o.name for o in task.objects if o.ripe is False}
        flagged = {p["object"] for p in per_object if p["overripe"]}
        rounds.append({"round": r + 1, "objects": per_object, "flagged": sorted(flagged),
                       "success": flagged == truth_overripe})
    summary = {"task": "ripeness", "d0_from": feat0, "threshold_mm": task.threshold_mm,
               "calibration": {"d0_slope": cal0.slope, "d1_slope": cal1.slope, "points": len(xs)},
               "rounds": rounds, "success_rate": sum(r["success"] for r in rounds) / len(rounds),
               **_timing(port, t0, w0)}
    return summary


TASKS = {"sorting": sorting, "picking": picking, "ripeness": ripeness}
