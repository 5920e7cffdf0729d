"""Pick and place with your own motion stack: the arm moved by ur_rtde from here, the
gripper by the fluidsense client.

    fluidsense simcell --config config/cell-gripper-modbus-sim.yaml &     # or a real UR box
    fluidsense run --config config/cell-gripper-modbus-sim.yaml &
    python examples/pick_and_place.py --robot 127.0.0.1

The arm's program is this script's (ur_rtde's control script): the daemon's cell config
must leave the arm to it (``arm: null``), as that one does; that is how the test suite runs
it. Without ``--robot`` the arm moves are only printed. The poses are the sorting task's slots
(config/tasks/sorting.yaml); change them for your cell.
"""

from __future__ import annotations

import argparse
import sys

from fluidsense.client import GripEnded, Gripper, Refused

PICK = [0.40, -0.20, 0.10, 0.0, 3.14, 0.0]
PLACE = [0.40, 0.20, 0.10, 0.0, 3.14, 0.0]
APPROACH_M = 0.05


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


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robot", help="the UR controller's address (ur_rtde); without it, moves are printed")
    p.add_argument("--cmd", default="tcp://127.0.0.1:5561")
    p.add_argument("--pub", default="tcp://127.0.0.1:5560")
    p.add_argument("--speed", type=float, default=0.25)
    p.add_argument("--acc", type=float, default=0.5)
    args = p.parse_args(argv)
    try:
        arm = Arm(args.robot, args.speed, args.acc)
    except RuntimeError as exc:  # ur_rtde: no robot there, or not in remote control
        print(f"pick_and_place: the robot at {args.robot}: {exc}", file=sys.stderr)
        return 3
    with Gripper(args.cmd, args.pub) as g:
        try:
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
