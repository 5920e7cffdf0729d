"""The command socket's request layer in-process: the dispatcher and its handlers on a fake
cell (support/requests.py), no controller, no sockets. The same requests go over real
sockets to a daemon in test_zmq.py, test_gripper.py and test_security.py.

And the lists that have one source: the request names (the models), the topics, the
grasp's features (the cycle result's published fields)."""

from __future__ import annotations

import asyncio

import pytest
from fluidsense.common import names
from fluidsense.common.errors import (
    CommandError,
    FluidsenseError,
    NotSupportedError,
    SafetyError,
    SequenceError,
)
from fluidsense.controller.requests.dispatch import NAMES, REQUESTS
from fluidsense.controller.requests.server import decode
from support.requests import BAD_REQUESTS, FakeCell, settle


def run(body):
    return asyncio.run(body())


async def answer(requests, frames):
    """What the command socket does with a body: decode it, hand it to the dispatcher."""
    try:
        return {"ok": True, **(await requests.answer(decode(frames)))}
    except (ValueError, FluidsenseError) as exc:
        return {"ok": False, "error": str(exc)}


# ------------------------------------------------------------------ one source per list
def test_the_light_name_list_is_the_models_names():
    """common/names.py lets the CLI list the requests without pydantic; the models are the
    source. A request added to a handler and not there fails here."""
    assert names.COMMANDS == NAMES
    assert len(REQUESTS) == len(NAMES) and {"status", "grip", "shutdown"} <= set(NAMES)


def test_the_fuzzer_sends_every_request_but_shutdown():
    from lab.bench.fuzz import FUZZ_COMMANDS

    assert set(NAMES) - {"shutdown"} <= set(FUZZ_COMMANDS) and "shutdown" not in FUZZ_COMMANDS


def test_topics_are_the_documented_ones_and_the_client_types_the_gripper_s():
    from fluidsense.client.types import TYPED
    from fluidsense.controller.telemetry import outlet
    from support.events import SCHEMAS

    assert set(names.TOPICS) == set(SCHEMAS)
    assert outlet.TOPICS is names.TOPICS and set(TYPED) == set(names.GRIPPER_TOPICS) <= set(names.TOPICS)


def test_a_grasp_carries_features_as_the_cycle_publishes_them():
    from fluidsense.controller.requests.grip import GRASP_FEATURES
    from support.events import SCHEMAS

    published = FakeCell().result(36.3).to_dict()
    assert set(GRASP_FEATURES) <= set(published)
    assert set(GRASP_FEATURES) == set(SCHEMAS["grasp"]["properties"]["features"]["required"])


# ------------------------------------------------------------------ what the socket refuses
def test_bad_requests_get_the_reasons_a_daemon_gives():
    cell = FakeCell(refuse=SafetyError("p0 95 kPa outside the profile's limits [-5.0, 90.0] kPa"))

    async def body():
        requests = cell.requests()
        return [(reason, await answer(requests, frames)) for frames, reason in BAD_REQUESTS]

    for reason, reply in run(body):
        assert reply["ok"] is False and reason in reply["error"], (reason, reply)
    assert cell.asked == [("start_cycle", 95, False, False)]  # the one that got as far as the cell


def test_an_unknown_request_lists_the_known_ones():
    async def body():
        return await answer(FakeCell().requests(), [b'{"cmd": "stat"}'])

    assert run(body)["error"] == f"unknown command 'stat'; known: {', '.join(names.COMMANDS)}"


def test_while_connecting_only_status_abort_and_shutdown_are_taken():
    cell = FakeCell(connected=False, connecting={"attempts": 3, "error": "connection refused"})
    stopped = []

    async def body():
        requests = cell.requests(shutdown=lambda: stopped.append(True))
        replies = {cmd: await answer(requests, [f'{{"cmd": "{cmd}"}}'.encode()])
                   for cmd in ("status", "cycle", "grip", "reset", "abort", "shutdown")}
        return replies

    replies = run(body)
    assert replies["status"]["ok"] and replies["status"]["state"] == "connecting"
    for cmd in ("cycle", "grip", "reset"):
        assert not replies[cmd]["ok"]
        assert replies[cmd]["error"].startswith("not connected to fake yet (connection refused)"), replies[cmd]
    assert replies["abort"] == {"ok": True, "aborted": False} and replies["shutdown"]["ok"] and stopped == [True]
    assert cell.asked == [("abort", "operator")]  # nothing else reached the cell


# ------------------------------------------------------------------ the requests on the cell
def test_cycle_reset_scene_and_status():
    cell = FakeCell()

    async def body():
        requests = cell.requests(socket_stats=lambda: {"handled": 7, "rejected": 1, "malformed_dropped": 0})
        started = await requests.answer({"cmd": "cycle", "store_reference": True})
        with pytest.raises(SequenceError, match="busy: cycle 1 is in charge"):
            await requests.answer({"cmd": "cycle"})
        status = await requests.answer({"cmd": "status"})
        scene = await requests.answer({"cmd": "scene", "scene": {"kind": "cylinder", "diameter_mm": 60}})
        reset = await requests.answer({"cmd": "reset"})
        return started, status, scene, reset

    started, status, scene, reset = run(body)
    assert started == {"cycle_id": 1} and reset == {"state": "idle"}
    assert status["state"] == "charge" and status["cycle_id"] == 1 and status["backend"] == "fake"
    assert status["commands"] == {"handled": 7, "rejected": 1, "malformed_dropped": 0} and status["task"] is None
    assert status["holding"] is False and status["gripper_op"] is None and status["last_grasp"] is None
    assert scene["scene"]["kind"] == "cylinder" and scene["scene"]["diameter_mm"] == 60
    assert [a[0] for a in cell.asked] == ["start_cycle", "start_cycle", "place", "reset"]


def test_a_bug_in_a_handler_vents_and_the_reply_says_so():
    cell = FakeCell()

    async def broken(scene):
        raise KeyError("injected")

    cell.place = broken  # the scene device fails in a way nobody foresaw

    async def body():
        requests = cell.requests()
        with pytest.raises(CommandError, match=r"internal error: KeyError: 'injected'; the cell was put in its safe "
                                               r"state \(send reset to go on\)"):
            await requests.answer({"cmd": "scene", "scene": {"kind": "none"}})

    run(body)
    assert cell.asked == [("fail", "KeyError handling 'scene': 'injected'")]


def test_shutdown_is_refused_where_there_is_no_daemon_to_stop():
    async def body():
        with pytest.raises(NotSupportedError, match="nothing to shut down"):
            await FakeCell().requests().answer({"cmd": "shutdown"})

    run(body)


# ------------------------------------------------------------------ tasks, one at a time
def test_a_task_runs_alone_and_abort_stops_it():
    cell = FakeCell()
    gate = {}

    def runner(file, order_mm):
        if file == "missing.yaml":
            raise CommandError("task file 'missing.yaml' is not a YAML file in /tasks")

        async def work():
            gate["started"] = order_mm
            await asyncio.Event().wait()  # runs until cancelled
            return {}

        return work()

    async def body():
        requests = cell.requests(tasks=runner)
        with pytest.raises(CommandError, match="not a YAML file"):
            await requests.answer({"cmd": "task", "file": "missing.yaml"})
        started = await requests.answer({"cmd": "task", "file": "sorting.yaml", "order_mm": [40, 60]})
        await settle()
        running = (await requests.answer({"cmd": "status"}))["task"]
        refused = []
        for request in ({"cmd": "task", "file": "sorting.yaml"}, {"cmd": "grip"}, {"cmd": "measure"}):
            with pytest.raises(SequenceError) as exc:
                await requests.answer(request)
            refused.append(str(exc.value))
        aborted = await requests.answer({"cmd": "abort", "reason": "operator"})
        await settle()
        return started, running, refused, aborted, (await requests.answer({"cmd": "status"}))["task"]

    started, running, refused, aborted, after = run(body)
    assert started == {"task": "sorting.yaml", "started": True} and gate["started"] == [40, 60]
    assert running == {"file": "sorting.yaml", "running": True}
    assert refused == ["busy: task sorting.yaml is running"] * 3
    assert aborted == {"aborted": True}  # no cycle ran: the task was what stopped
    assert after == {"file": "sorting.yaml", "running": False}
    assert ("task", {"task": "sorting.yaml", "event": "aborted"}) in cell.events


@pytest.mark.parametrize("failure, asked", [
    (SafetyError("the arm is in a protective stop"), ("abort", "task failed: the arm is in a protective stop")),
    (ZeroDivisionError("a bug"), ("fail", "task sorting.yaml: ZeroDivisionError: a bug")),
])
def test_a_task_that_fails_is_reported_and_a_bug_in_one_vents(failure, asked):
    """A task that cannot go on (a FluidsenseError) has its cycle aborted and the daemon
    goes on; anything else is a bug: the cell is vented with the reason."""
    cell = FakeCell()

    def runner(file, order_mm):
        async def work():
            await cell.start_cycle()
            raise failure

        return work()

    async def body():
        requests = cell.requests(tasks=runner)
        await requests.answer({"cmd": "task", "file": "sorting.yaml"})
        await settle()
        return (await requests.answer({"cmd": "status"}))["task"]

    assert run(body) == {"file": "sorting.yaml", "running": False}
    assert cell.asked[-1] == asked


def test_no_task_runner_no_task():
    async def body():
        with pytest.raises(NotSupportedError, match="runs no tasks"):
            await FakeCell().requests().answer({"cmd": "task", "file": "sorting.yaml"})

    run(body)


def test_a_request_finds_its_method_even_where_the_handler_keeps_state_of_that_name():
    """GripHandler keeps ``last_grasp``: a request of that name must still reach its method."""
    from typing import Literal

    from fluidsense.common.models import StrictModel
    from fluidsense.controller.requests.routing import Routes, answers

    class PingRequest(StrictModel):
        cmd: Literal["ping"]

    class Handler:
        def __init__(self):
            self.ping = None  # state under the request's name

        @answers(PingRequest)
        async def ping(self, req: PingRequest) -> dict:
            return {"pong": True}

    routes = Routes(Handler())
    request = routes.parse({"cmd": "ping"})
    assert routes.names == ("ping",) and run(lambda: routes.method(request)(request)) == {"pong": True}
