"""``--actuate``: pulse each valve in turn and check that the pressures answer as the
wiring says. Each step sets some valves and says, per pressure channel, whether it must
move towards the test pressure (+1), back towards zero (-1) or stay (0); what the
channels did instead names the valve and the likely cause (swapped outputs, an
inverted normally-open valve, no air, a dead sensor, a leak).

The caller always ends in the safe state (``finish``), whatever happened here."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

from fluidsense.common.hardware import SUPPLY, VENT, TankCircuit
from fluidsense.common.units import KPA
from fluidsense.drivers.backend import Backend

from .findings import Findings
from .readings import Rig

log = logging.getLogger(__name__)

#: a change smaller than this share of the test pressure (or 0.5 kPa) is "stayed"
MOVE_SHARE, MOVE_MIN_KPA = 0.1, 0.5


class Unsafe(Exception):  # noqa: N818 - a reason to stop pulsing, not an error of ours
    """A pressure left the profile's limits: stop pulsing at once."""


@dataclass(frozen=True)
class Step:
    label: str
    valve: str | None  # the valve under test, None for the regulator step
    positions: dict[str, bool] = field(default_factory=dict)
    expect: dict[str, int] = field(default_factory=dict)
    regulator: bool = False  # this step raises the regulator to the test pressure


def plan(circuit, channels: tuple[str, ...]) -> list[Step]:
    """The steps for a tank or regulated circuit (others: none)."""
    def only(expect: dict[str, int]) -> dict[str, int]:
        return {ch: sign for ch, sign in expect.items() if ch in channels}

    if isinstance(circuit, TankCircuit):
        steps = [
            Step("regulator up, every valve at its safe position", None, {}, only({"p_tank": 0, "p_act": 0}), True),
            Step("supply open", SUPPLY, {SUPPLY: True}, only({"p_tank": 1, "p_act": 0})),
            Step("supply closed", SUPPLY, {SUPPLY: False}, only({"p_tank": 0, "p_act": 0})),
        ]
        if circuit.vent_valve:
            return steps + [
                Step("vent closed, actuate open", "actuate", {VENT: False, "actuate": True},
                     only({"p_act": 1, "p_tank": -1})),
                Step("actuate closed (vent still closed: held)", "actuate", {"actuate": False},
                     only({"p_act": 0, "p_tank": 0})),
                Step("vent open", VENT, {VENT: True}, only({"p_act": -1, "p_tank": 0})),
            ]
        return steps + [
            Step("actuate open", "actuate", {"actuate": True}, only({"p_act": 1, "p_tank": -1})),
            Step("actuate closed (vents)", "actuate", {"actuate": False}, only({"p_act": -1, "p_tank": 0})),
        ]
    if circuit.kind == "regulated":
        return [
            Step("regulator up, actuate at its safe position", None, {}, only({"p_tank": 1, "p_act": 0}), True),
            Step("actuate open", "actuate", {"actuate": True}, only({"p_act": 1})),
            Step("actuate closed (vents)", "actuate", {"actuate": False}, only({"p_act": -1})),
        ]
    return []


def test_pressure_pa(profile, test_kpa: float | None) -> float:
    """Half the profile's p0, at most 20 kPa either way, inside the limits: enough to see
    every valve's effect, gentle on a gripper that turns out to be miswired."""
    kpa = test_kpa if test_kpa is not None else max(-20.0, min(20.0, profile.sequence.p0_kpa / 2))
    lo, hi = profile.limits.min_kpa, profile.limits.max_kpa
    return max(lo, min(hi, kpa)) * KPA


def _word(sign: int, ch: str) -> str:
    return {1: f"{ch} to move towards the test pressure", -1: f"{ch} to fall back towards 0",
            0: f"{ch} to stay"}[sign]


def _saw(moved: dict[str, float]) -> str:
    return ", ".join(f"{ch} {d / KPA:+.1f} kPa" for ch, d in moved.items())


class Pulser:
    def __init__(self, backend: Backend, rig: Rig, profile, out: Findings, p_test_pa: float, pulse_s: float):
        self.backend, self.rig, self.out = backend, rig, out
        self.p_test, self.pulse_s = p_test_pa, pulse_s
        self.limits = (profile.limits.min_pa, profile.limits.max_pa)
        self.wiring = getattr(backend.valves, "wiring", None)
        self.seen: dict[str, dict[str, int]] = {}  # step label -> observed signs

    def name(self, valve: str) -> str:
        if self.wiring is not None and valve in self.wiring:
            w = self.wiring[valve]
            return f"valve {valve} (output {w.output}{', normally open' if not w.open_when_energised else ''})"
        return f"valve {valve}"

    async def level(self) -> dict[str, float]:
        levels = await self.rig.level(self.pulse_s)
        for ch, p in levels.items():
            if ch != "flow" and not self.limits[0] <= p <= self.limits[1]:
                raise Unsafe(f"{ch} reached {p / KPA:+.1f} kPa, outside the profile's limits "
                             f"[{self.limits[0] / KPA:g}, {self.limits[1] / KPA:g}] kPa")
        return levels

    async def run(self, steps: list[Step]) -> None:
        out = self.out
        threshold = max(MOVE_MIN_KPA * KPA, MOVE_SHARE * abs(self.p_test))
        sign = 1.0 if self.p_test >= 0 else -1.0
        before = await self.level()
        for step in steps:
            if step.regulator:
                await self.backend.regulator.set_setpoint(self.p_test, self.rig.now)
            for valve, is_open in step.positions.items():
                await self.backend.valves.set(valve, is_open, self.rig.now)
            after = await self.level()
            moved = {ch: after[ch] - before[ch] for ch in step.expect}
            seen = {ch: (1 if d * sign > threshold else -1 if d * sign < -threshold else 0) for ch, d in moved.items()}
            self.seen[step.label] = seen
            if seen == step.expect:
                out.info(f"{step.label}: as wired ({_saw(moved)})")
            elif step.valve is None:
                self._safe_state_leaks(step, seen, moved)
                return  # nothing after this can be read: stop pulsing
            else:
                self._mismatch(step, steps, seen, moved)
            before = after

    def _safe_state_leaks(self, step: Step, seen: dict[str, int], moved: dict[str, float]) -> None:
        feeds = {"p_tank": SUPPLY, "p_act": "actuate"}  # which valve lets pressure to which sensor
        for ch, s in seen.items():
            if s != step.expect[ch] and s == 1 and feeds.get(ch) in self.backend.valves.names:
                valve = feeds[ch]
                self.out.problem(self.name(valve), f"pressure reached {ch} ({moved[ch] / KPA:+.1f} kPa) with every "
                                 "valve at what the wiring calls its safe position: this valve is open there",
                                 "its output is another valve's (swapped outputs in wiring.valves) or "
                                 "open_when_energised is wrong; the daemon's safe state would not vent: fix the "
                                 "wiring section before running it")
            elif s != step.expect[ch]:
                self.out.problem(ch, f"{step.label}: expected {_word(step.expect[ch], ch)}, saw "
                                 f"{moved[ch] / KPA:+.1f} kPa", "check the regulator's wiring and the sensor")

    def _mismatch(self, step: Step, steps: list[Step], seen: dict[str, int], moved: dict[str, float]) -> None:
        subject = self.name(step.valve)
        expected = ", ".join(_word(s, ch) for ch, s in step.expect.items())
        like = [o for o in steps if o.valve not in (None, step.valve) and o.expect == seen and any(seen.values())]
        if like:
            other = like[0].valve
            todo = (f"the outputs of {step.valve} and {other} look swapped: check which output each valve is on "
                    f"(wiring.valves.{step.valve}.output, wiring.valves.{other}.output)")
            found = f"{step.label}: answered as '{like[0].label}' should ({_saw(moved)}; expected {expected})"
        elif not any(seen.values()):
            found = f"{step.label}: no pressure answered ({_saw(moved)}; expected {expected})"
            todo = ("the valve is not on that output, has no air, or a sensor is dead: check the valve's cable and "
                    "output, the supply pressure, and the sensors")
        elif all(s == -e for ch, s in seen.items() for e in [step.expect[ch]] if e):
            found = f"{step.label}: the pressure moved the opposite way ({_saw(moved)}; expected {expected})"
            todo = f"an inverted valve: set wiring.valves.{step.valve}.open_when_energised to the valve's type"
        elif any(e == 0 and s == -1 for ch, s in seen.items() for e in [step.expect[ch]]):
            found = f"{step.label}: pressure fell where it should hold ({_saw(moved)}; expected {expected})"
            todo = "a leak (tubing, fittings, the actuator) or a valve that does not close"
        else:
            found = f"{step.label}: {_saw(moved)} (expected {expected})"
            todo = "check the valve's output and type, and the sensors' wiring"
        self.out.problem(subject, found, todo)


async def finish(backend: Backend, rig: Rig, out: Findings) -> bool:
    """Regulator to zero, every valve to its safe position, read back. Tries everything;
    True only when the device confirms the safe positions."""
    t = rig.now
    ok = True
    if backend.regulator is not None:
        try:
            await backend.regulator.set_setpoint(0.0, t)
        except Exception as exc:  # noqa: BLE001 - the valves must still be vented
            out.problem("regulator", f"could not set it to 0 kPa: {exc}", "turn the supply pressure off by hand")
            ok = False
    try:
        confirmed = await backend.safe_state(t)
    except Exception as exc:  # noqa: BLE001 - reported, the person must vent by hand
        out.problem("safe state", f"could not put the valves in their safe positions: {exc}",
                    "vent the gripper by hand (pendant, or the valves' manual override)")
        return False
    if confirmed is True:
        out.info("every valve at its safe position, confirmed by read-back")
    elif confirmed is None:
        out.info("every valve commanded to its safe position (this device cannot report its outputs)")
    else:
        out.problem("safe state", f"the device reports {backend.valves.reported} after the safe positions were "
                    "written", "vent the gripper by hand and look for what holds the outputs")
        ok = False
    return ok
