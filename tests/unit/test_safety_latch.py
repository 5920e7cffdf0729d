"""The safety latch: whatever fails inside the service, the cell ends vented (as the
device reports), the fault is latched and published, and nobody is left waiting.

(Its tests with real peers: tests/system/test_safety_latch.py.)
"""

from __future__ import annotations

import asyncio

import pytest
from fluidsense.common.errors import CommandError, FaultError
from fluidsense.common.scenes import CylinderScene
from fluidsense.controller.config import CellConfig, load_profile
from fluidsense.controller.cycles.sequencer import State
from fluidsense.controller.service import Controller, Sink
from fluidsense.controller.telemetry.publisher import NullPublisher
from fluidsense.drivers.registry import SimDriverConfig, build_backend
from support.harness import CONFIG

#: a hang fails the test instead of the suite; nothing below waits on wall time otherwise
HANG_S = 60.0


class Probe(NullPublisher):
    """A publisher that keeps what it is given; ``fail_on`` makes one topic raise once."""

    def __init__(self) -> None:
        super().__init__()
        self.sent: list[tuple[str, dict]] = []
        self.fail_on: str | None = None

    def send(self, topic: str, t_s: float, payload: dict) -> None:
        if topic == self.fail_on:
            self.fail_on = None
            raise RuntimeError(f"cannot publish {topic}")
        self.sent.append((topic, payload))


class Boom(RuntimeError):
    pass


def _cfg(seed: int = 3) -> CellConfig:
    prof = load_profile(CONFIG / "profiles" / "pneunet-gripper.yaml")
    seq = prof.sequence.model_copy(update={"charge_s": 2.0, "isolate_s": 1.0, "actuate_s": 8.0, "vent_s": 2.0})
    return CellConfig(driver=SimDriverConfig(clock="virtual", seed=seed), profile=prof.model_copy(update={"sequence": seq}))


def _once(fn, when):
    """``fn`` that raises Boom the first time ``when()`` holds, and works otherwise."""
    state = {"armed": True}

    def wrapped(*args, **kwargs):
        if state["armed"] and when():
            state["armed"] = False
            raise Boom("injected")
        return fn(*args, **kwargs)

    return wrapped


def _inject(stage: str, ctrl: Controller, probe: Probe) -> None:
    actuating = lambda: ctrl.cycles.sequencer.state in (State.ACTUATE, State.HOLD)  # noqa: E731
    if stage == "supervisor":
        ctrl.supervisor.check = _once(ctrl.supervisor.check, actuating)
    elif stage == "sequencer":
        ctrl.cycles.sequencer.on_time = _once(ctrl.cycles.sequencer.on_time, actuating)
    elif stage == "features":
        ctrl.cycles._analyse = _once(ctrl.cycles._analyse, lambda: True)
    elif stage == "publisher":
        probe.fail_on = "heartbeat"
    elif stage == "sink":
        class Broken(Sink):
            def on_block(self, block) -> None:
                if actuating():
                    raise Boom("injected")
        ctrl.add_sink(Broken())
    elif stage == "valve write":
        valves = ctrl.backend.valves

        async def refuse(valve, open_, t, _set=valves._set):
            if valve == "actuate" and open_ and not getattr(valves, "_refused", False):
                valves._refused = True
                raise Boom("injected: the output driver refused")
            await _set(valve, open_, t)

        valves._set = refuse
    elif stage == "source":
        src = ctrl.backend.source

        async def read(_read=src._read_block):
            if actuating() and not getattr(src, "_failed", False):
                src._failed = True
                raise Boom("injected")
            return await _read()

        src._read_block = read


EXPECTED = {"supervisor": "internal", "sequencer": "internal", "features": "internal", "publisher": "internal",
            "sink": "internal", "valve write": "command", "source": "driver"}


@pytest.mark.parametrize("stage", list(EXPECTED))
def test_an_exception_at_any_stage_latches_vents_and_releases_every_waiter(stage):
    async def body():
        probe = Probe()
        cfg = _cfg()
        ctrl = Controller(cfg, build_backend(cfg.driver, cfg.profile.hardware), probe)
        async with ctrl:
            await ctrl.scene.place(CylinderScene(diameter_mm=60))
            _inject(stage, ctrl, probe)
            fut = await ctrl.start_cycle(hold=True)  # held: without the fault it would wait for a release
            waiter = asyncio.ensure_future(ctrl.wait(1000.0))
            result = await asyncio.wait_for(fut, HANG_S)
            with pytest.raises(FaultError):
                await asyncio.wait_for(waiter, HANG_S)
            fault = ctrl.fault
            reported = dict(ctrl.backend.valves.reported)
            vented = ctrl.latch.vented()
            with pytest.raises(FaultError, match="send reset"):
                await ctrl.start_cycle()
            ctrl.reset()
            after = await asyncio.wait_for(ctrl.run_cycle(), HANG_S)
            return fault, result, reported, vented, probe.sent, after, ctrl.backend.valves.safe_positions

    fault, result, reported, vented, sent, after, safe = asyncio.run(body())
    assert fault is not None and fault.kind == EXPECTED[stage], fault
    assert result.aborted == f"fault: {EXPECTED[stage]}"
    assert reported == safe and vented is True
    events = [p for t, p in sent if t == "fault"]
    assert len(events) == 1 and events[0]["kind"] == EXPECTED[stage] and events[0]["vented"] is True
    assert events[0]["outputs"] == safe
    assert after.ok  # reset, and the cell works again


def test_a_failing_command_handler_vents_and_answers_with_the_reason():
    async def body():
        cfg = _cfg()
        ctrl = Controller(cfg, build_backend(cfg.driver, cfg.profile.hardware), Probe())
        async with ctrl:
            from fluidsense.controller.requests.dispatch import SceneRequest
            from fluidsense.controller.requests.wiring import wire

            async def broken(scene, t):
                raise Boom("injected in the scene device")

            ctrl.backend.scene.set_scene = broken
            await ctrl.start_cycle(hold=True)
            await ctrl.wait(5.0)
            inflated = ctrl.backend.valves.reported["actuate"]
            with pytest.raises(CommandError, match="internal error.*safe state"):
                await wire(ctrl).handle(SceneRequest(cmd="scene", scene={"kind": "none"}))
            return inflated, ctrl.fault, ctrl.latch.vented()

    inflated, fault, vented = asyncio.run(body())
    assert inflated  # the actuation valve was open when the command failed
    assert fault.kind == "internal" and "scene" in fault.detail and vented is True


def test_a_second_fault_does_not_replace_the_first():
    async def body():
        cfg = _cfg()
        ctrl = Controller(cfg, build_backend(cfg.driver, cfg.profile.hardware), Probe())
        async with ctrl:
            cell = ctrl.backend.sim
            fut = await ctrl.start_cycle()
            cell.inject("sensor_nan", ctrl.now + 4.0)
            await asyncio.wait_for(fut, HANG_S)
            first = ctrl.fault
            cell.inject("leak", ctrl.now)
            await ctrl.wait(3.0)
            return first, ctrl.fault

    first, later = asyncio.run(body())
    assert first.kind == "sensor_nan" and later is first
