"""Pick and place with your own motion stack: the arm moved by ur_rtde from here, the
gripper by the fluidsense client.

    fluidsense simcell --config config/cell-gripper-modbus-sim.yaml &     # or a real UR box
    fluidsense run --config config/cell-gripper-modbus-sim.yaml &
    python examples/pick_and_place.py --config config/cell-gripper-modbus-sim.yaml --emulated-object 60

``--config`` reads from the daemon's cell config where the daemon listens (``publisher``)
and where the robot is (``driver.host``); ``--cmd``, ``--pub`` and ``--robot`` say it
instead. The arm's program is this script's (ur_rtde's control script): the daemon's cell
config must leave the arm to it (``arm: null``), as that one does. Without a robot the arm
moves are only printed. The poses are the sorting task's slots (config/tasks/sorting.yaml);
change them for your cell.

Before it grips, the gripper needs a free-air reference (a measure with nothing in it) to
tell an object from none: if the daemon has none, this script takes one first, with the
arm where it starts (keep the fingers clear there). And an object must be at the pick
slot: on a real cell, put it there; against the emulated box, ``--emulated-object
DIAMETER_MM`` lays a cylinder there through the box's sim control port
(``driver.sim_control_port``).

Ctrl-C, SIGTERM (systemd, ``docker stop``, ``timeout``) and SIGHUP (a closed terminal)
stop it the same way: the arm's script stopped, the gripper's cycle aborted (the daemon
vents), the vent confirmed from the daemon's status, exit 128 + the signal's number
(130, 143, 129).
"""

from __future__ import annotations

import argparse
import json
import socket
import sys

from fluidsense.client import GripEnded, Gripper, Refused
from fluidsense.common.stopsignals import interruption, raise_on_stop_signals

PICK = [0.40, -0.20, 0.10, 0.0, 3.14, 0.0]
PLACE = [0.40, 0.20, 0.10, 0.0, 3.14, 0.0]
APPROACH_M = 0.05
READY_WAIT_S = 120.0  # a daemon started a moment ago connects to its box first


class Arm:
    """ur_rtde's RTDEControlInterface, or a stand-in that prints the moves."""

    def __init__(self, host: str | None, speed: float, acc: float):
        self.speed, self.acc = speed, acc
        self.rtde = None
        if host is not None:
            import rtde_control  # ur_rtde

            self.rtde = rtde_control.RTDEControlInterface(host)

    def move(self, pose: list[float], what: str) -> None:
        print(f"arm: {what} {pose}")
        if self.rtde is not None:
            self.rtde.moveL(pose, self.speed, self.acc)

    def above(self, pose: list[float]) -> list[float]:
        return [pose[0], pose[1], pose[2] + APPROACH_M, *pose[3:]]

    def close(self) -> None:
        if self.rtde is not None:
            self.rtde.stopScript()


def place_emulated_object(host: str, port: int, diameter_mm: float) -> None:
    """The emulated box's world: a cylinder at the pick slot, the place slot empty."""
    world = {"slots": [{"name": "pick", "pose": PICK, "object": "cylinder"}, {"name": "place", "pose": PLACE}],
             "objects": [{"name": "cylinder", "diameter_mm": diameter_mm, "min_grip_kpa": 0.5}]}
    with socket.create_connection((host, port), timeout=10) as sock:
        sock.sendall(json.dumps({"cmd": "world", "world": world}).encode() + b"\n")
        reply = json.loads(sock.makefile().readline() or "{}")
    if not reply.get("ok"):
        raise RuntimeError(f"the emulated box at {host}:{port} did not take the world: {reply}")


def from_config(path: str) -> dict:
    """The daemon's endpoints, the robot's address and the emulated box's control port."""
    import yaml

    with open(path) as f:
        cfg = yaml.safe_load(f)
    pub = cfg.get("publisher") or {}
    driver = cfg.get("driver") or {}
    return {"cmd": pub.get("cmd"), "pub": pub.get("pub"), "robot": driver.get("host"),
            "sim_control_port": driver.get("sim_control_port")}


def wait_until_ready(g: Gripper) -> dict:
    """The daemon's status once it has connected to its devices (it refuses grips before)."""
    import time

    deadline = time.monotonic() + READY_WAIT_S
    while (status := g.status())["state"] == "connecting" and time.monotonic() < deadline:
        time.sleep(0.5)  # a person's script polling a daemon that is still connecting
    return status


def vent_on_stop(cmd: str, why: str, confirm_s: float = 3.0) -> str:
    """Abort whatever the gripper does (the daemon vents) and say what the daemon then
    reports, once its read-back of the outputs is newer than the abort (within
    ``confirm_s``). A new connection: the one interrupted may be stuck mid-request."""
    import time

    with Gripper(cmd, None, timeout_s=10.0) as g:
        aborted_at = time.monotonic()
        said = "a cycle aborted" if g.abort(why) else "no cycle was running"
        while True:
            status = g.status()
            age = status["valves_age_s"]
            fresh = age is not None and age < time.monotonic() - aborted_at
            settled = status["state"] in ("idle", "vent", "fault")
            if fresh and settled and status["valves"] == status["valves_commanded"]:
                return f"{said}; the daemon reads the valves back at {status['valves']}: vented"
            if time.monotonic() - aborted_at > confirm_s:
                return (f"{said}; the daemon reports state {status['state']}, valves {status['valves']} (commanded "
                        f"{status['valves_commanded']}, read {age} s ago): check that the gripper is vented")
            time.sleep(0.05)  # a person's script polling the daemon's read-back


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robot", help="the UR controller's address (ur_rtde); without it, moves are printed")
    p.add_argument("--config", help="the daemon's cell config: its endpoints and the robot's address")
    p.add_argument("--cmd", help="the daemon's command endpoint (default tcp://127.0.0.1:5561)")
    p.add_argument("--pub", help="the daemon's event endpoint (default tcp://127.0.0.1:5560)")
    p.add_argument("--emulated-object", type=float, metavar="DIAMETER_MM",
                   help="emulated box only: put a cylinder this wide at the pick slot first")
    p.add_argument("--speed", type=float, default=0.25)
    p.add_argument("--acc", type=float, default=0.5)
    args = p.parse_args(argv)
    cfg = from_config(args.config) if args.config else {}
    args.cmd = args.cmd or cfg.get("cmd") or "tcp://127.0.0.1:5561"
    args.pub = args.pub or cfg.get("pub") or "tcp://127.0.0.1:5560"
    args.robot = args.robot or cfg.get("robot")
    if args.emulated_object is not None and (not args.robot or not cfg.get("sim_control_port")):
        p.error("--emulated-object needs --config naming the emulated box (driver.host, driver.sim_control_port)")
    try:
        with raise_on_stop_signals():
            return pick_and_place(args, cfg)
    except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM, SIGHUP: the arm's script is stopped already (finally)
        sig = interruption(exc)
        print(f"pick_and_place: stopped by {sig.name}; {vent_on_stop(args.cmd, f'pick_and_place: {sig.name}')}",
              file=sys.stderr, flush=True)
        return sig.exit_code


def pick_and_place(args: argparse.Namespace, cfg: dict) -> int:
    with Gripper(args.cmd, args.pub, timeout_s=30.0) as g:
        status = wait_until_ready(g)  # and so is the box: the daemon has connected to it
        if args.emulated_object is not None:
            place_emulated_object(args.robot, cfg["sim_control_port"], args.emulated_object)
        try:
            arm = Arm(args.robot, args.speed, args.acc)
        except RuntimeError as exc:  # ur_rtde: no robot there, or not in remote control
            print(f"pick_and_place: the robot at {args.robot}: {exc}", file=sys.stderr)
            return 3
        try:
            if not status.get("references_kpa"):  # object or not cannot be told without one
                ref = g.measure(store_reference=True)
                print(f"free-air reference taken (cycle {ref.cycle_id})")
            arm.move(arm.above(PICK), "approach")
            arm.move(PICK, "pick")
            grasp = g.grip()
            size = grasp.size
            print(f"grasp: object {grasp.object}, "
                  + (f"{size.quantity} {size.value_mm} mm [{size.lo_mm}, {size.hi_mm}] ({size.status})"
                     if size else "no calibration"))
            if grasp.object is False:
                g.release()
                arm.move(arm.above(PICK), "retract (nothing there)")
                return 1
            arm.move(arm.above(PICK), "lift")
            arm.move(arm.above(PLACE), "carry")
            arm.move(PLACE, "place")
            released = g.release()
            print(f"released after {released.held_s} s held ({released.reason})")
            arm.move(arm.above(PLACE), "retract")
        except GripEnded as exc:
            print(f"the grip ended: {exc}", file=sys.stderr)
            return 4
        except Refused as exc:  # e.g. the daemon is in FAULT: it needs a reset first
            print(f"pick_and_place: {exc}", file=sys.stderr)
            return 2
        finally:
            arm.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
