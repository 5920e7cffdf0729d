"""A ROS 2 node serving control_msgs/action/GripperCommand over the fluidsense daemon.

Not run by the test suite (rclpy is not installable from the package index: install ROS 2
and run it with its Python). The mapping (docs/zmq-schema.md, "ROS 2 GripperCommand"):

    goal command.position == 0      -> release
    goal command.max_effort (kPa)   -> grip p0_kpa (0: the profile's P0)
    result position (m)             <- grasp size estimate (value_mm / 1000), 0 with no object
    result effort                   <- held P_eq (kPa)
    result stalled                  <- grasp.object is true (closed on something)
    result reached_goal             <- grasp.object is false (closed fully) or released

Slips are published on ``~/slip`` (std_msgs/Float64: the size after the slip, mm).

    ros2 run --prefix 'python3' ... or: python3 examples/ros2_gripper_node.py
"""

from __future__ import annotations

import threading

import rclpy
from control_msgs.action import GripperCommand
from fluidsense.client import GripEnded, Gripper, Refused, Slip
from rclpy.action import ActionServer
from rclpy.node import Node
from std_msgs.msg import Float64


class FluidsenseGripper(Node):
    def __init__(self) -> None:
        super().__init__("fluidsense_gripper")
        cmd = self.declare_parameter("cmd", "tcp://127.0.0.1:5561").value
        pub = self.declare_parameter("pub", "tcp://127.0.0.1:5560").value
        self.gripper = Gripper(cmd, pub)
        self.lock = threading.Lock()  # the client is not thread-safe
        self.slip_pub = self.create_publisher(Float64, "~/slip", 10)
        self.server = ActionServer(self, GripperCommand, "~/gripper_cmd", self.execute)
        self.create_timer(0.1, self.poll_slips)

    def execute(self, goal_handle):
        cmd = goal_handle.request.command
        result = GripperCommand.Result()
        with self.lock:
            try:
                if cmd.position == 0.0:
                    self.gripper.release()
                    result.reached_goal = True
                else:
                    grasp = self.gripper.grip(p0_kpa=cmd.max_effort or None)
                    size = grasp.size
                    result.position = (size.value_mm or 0.0) / 1000 if size and grasp.object else 0.0
                    result.effort = float(grasp.features.get("p_eq_kpa") or 0.0)
                    result.stalled = bool(grasp.object)
                    result.reached_goal = grasp.object is False
            except (Refused, GripEnded) as exc:
                self.get_logger().error(str(exc))
                goal_handle.abort()
                return result
        goal_handle.succeed()
        return result

    def poll_slips(self) -> None:
        if not self.lock.acquire(blocking=False):
            return
        try:
            ev = self.gripper.next_event(0)
            while ev is not None:
                if ev.topic == "slip":
                    est = Slip.of(ev).estimates
                    self.slip_pub.publish(Float64(data=float(est[0].value_mm or 0.0) if est else 0.0))
                ev = self.gripper.next_event(0)
        finally:
            self.lock.release()


def main() -> None:
    rclpy.init()
    node = FluidsenseGripper()
    try:
        rclpy.spin(node)
    finally:
        node.gripper.close()
        rclpy.shutdown()


if __name__ == "__main__":
    main()
