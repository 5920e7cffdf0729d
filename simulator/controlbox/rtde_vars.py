"""The RTDE variable table: name -> type -> where the value comes from (or goes to).

Names and types follow UR's RTDE guide for PolyScope 5.x. Outputs the emulator has no
model for (joint data, currents, temperatures, tool I/O, euromap) are sent as zeros of
the right type, so every variable ur_rtde 1.6.5's Receive and Control interfaces ask
for is accepted. An unknown name gets ``NOT_FOUND``, as on a real controller.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from fluidsense.simulator.controlbox.registers import Registers

if TYPE_CHECKING:  # pragma: no cover
    from fluidsense.simulator.controlbox.box import ControlBox

#: struct format of each RTDE type (big-endian on the wire)
FORMATS = {
    "BOOL": "?", "UINT8": "B", "UINT32": "I", "UINT64": "Q", "INT32": "i", "DOUBLE": "d",
    "VECTOR3D": "3d", "VECTOR6D": "6d", "VECTOR6INT32": "6i", "VECTOR6UINT32": "6I",
}
_ZERO = {"BOOL": False, "VECTOR3D": (0.0,) * 3, "VECTOR6D": (0.0,) * 6,
         "VECTOR6INT32": (0,) * 6, "VECTOR6UINT32": (0,) * 6}

_V6 = "VECTOR6D"
OUTPUT_TYPES: dict[str, str] = {
    "timestamp": "DOUBLE",
    **dict.fromkeys(["target_q", "target_qd", "target_qdd", "target_current", "target_moment",
                     "actual_q", "actual_qd", "actual_current", "actual_current_window",
                     "joint_control_output", "actual_TCP_pose", "actual_TCP_speed",
                     "actual_TCP_force", "target_TCP_pose", "target_TCP_speed",
                     "joint_temperatures", "actual_joint_voltage", "ft_raw_wrench",
                     "payload_inertia", "actual_current_as_torque"], _V6),
    "actual_digital_input_bits": "UINT64",
    "actual_digital_output_bits": "UINT64",
    "actual_execution_time": "DOUBLE",
    "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32",
    "safety_status": "INT32",
    "actual_tool_accelerometer": "VECTOR3D",
    "speed_scaling": "DOUBLE",
    "target_speed_fraction": "DOUBLE",
    "actual_momentum": "DOUBLE",
    "actual_main_voltage": "DOUBLE",
    "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE",
    "runtime_state": "UINT32",
    "elbow_position": "VECTOR3D",
    "elbow_velocity": "VECTOR3D",
    "robot_status_bits": "UINT32",
    "safety_status_bits": "UINT32",
    "analog_io_types": "UINT32",
    "standard_analog_input0": "DOUBLE",
    "standard_analog_input1": "DOUBLE",
    "standard_analog_output0": "DOUBLE",
    "standard_analog_output1": "DOUBLE",
    "io_current": "DOUBLE",
    "euromap67_input_bits": "UINT32",
    "euromap67_output_bits": "UINT32",
    "euromap67_24V_voltage": "DOUBLE",
    "euromap67_24V_current": "DOUBLE",
    "tool_mode": "UINT32",
    "tool_analog_input_types": "UINT32",
    "tool_analog_input0": "DOUBLE",
    "tool_analog_input1": "DOUBLE",
    "tool_output_voltage": "INT32",
    "tool_output_current": "DOUBLE",
    "tool_temperature": "DOUBLE",
    "tcp_force_scalar": "DOUBLE",
    "tool_output_mode": "UINT8",
    "tool_digital_output0_mode": "UINT8",
    "tool_digital_output1_mode": "UINT8",
    "payload": "DOUBLE",
    "payload_cog": "VECTOR3D",
    "script_control_line": "UINT32",
    "joint_position_deviation_ratio": "DOUBLE",
    "collision_detection_ratio": "DOUBLE",
    "time_scale_source": "UINT32",
}

INPUT_TYPES: dict[str, str] = {
    "speed_slider_mask": "UINT32",
    "speed_slider_fraction": "DOUBLE",
    "standard_digital_output_mask": "UINT8",
    "standard_digital_output": "UINT8",
    "configurable_digital_output_mask": "UINT8",
    "configurable_digital_output": "UINT8",
    "tool_digital_output_mask": "UINT8",
    "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8",
    "standard_analog_output_type": "UINT8",
    "standard_analog_output_0": "DOUBLE",
    "standard_analog_output_1": "DOUBLE",
    "external_force_torque": _V6,
}

Getter = Callable[["ControlBox"], Any]

_SOURCES: dict[str, Getter] = {
    "timestamp": lambda b: b.model.t,
    "actual_TCP_pose": lambda b: b.model.tcp_pose,
    # the kinematic arm tracks its setpoint exactly, so target and actual coincide
    "target_TCP_pose": lambda b: b.model.tcp_pose,
    "actual_TCP_speed": lambda b: b.model.tcp_speed,
    "target_TCP_speed": lambda b: b.model.tcp_speed,
    "actual_digital_input_bits": lambda b: b.image_digital_inputs,
    "actual_digital_output_bits": lambda b: b.model.digital_outputs,
    "robot_mode": lambda b: int(b.model.robot_mode),
    "safety_mode": lambda b: int(b.model.safety_mode),
    "safety_status": lambda b: int(b.model.safety_mode),
    "runtime_state": lambda b: int(b.runtime_state),
    "robot_status_bits": lambda b: b.robot_status_bits(),
    "safety_status_bits": lambda b: b.safety_status_bits(),
    "speed_scaling": lambda b: b.model.speed_fraction,
    "target_speed_fraction": lambda b: b.model.speed_fraction,
    "analog_io_types": lambda b: b.analog_io_types(),
    "standard_analog_input0": lambda b: b.rtde_analog_value(b.image_analog_inputs[0]),
    "standard_analog_input1": lambda b: b.rtde_analog_value(b.image_analog_inputs[1]),
    "standard_analog_output0": lambda b: b.rtde_analog_value(b.model.analog_output(0)),
    "standard_analog_output1": lambda b: b.rtde_analog_value(b.model.analog_output(1)),
}


def output_type(name: str) -> str | None:
    """Type of an output variable (inputs registers can be read back too), or None."""
    return OUTPUT_TYPES.get(name) or Registers.type_of(name)


def input_type(name: str) -> str | None:
    """Type of an input variable, or None."""
    if name in INPUT_TYPES:
        return INPUT_TYPES[name]
    return Registers.type_of(name) if name.startswith("input_") else None


def output_getter(name: str) -> Getter:
    """How to read output ``name`` from a box (a constant zero where nothing is modelled)."""
    if name in _SOURCES:
        return _SOURCES[name]
    if Registers.type_of(name):
        return lambda b: b.registers.read(name)
    zero = _ZERO.get(OUTPUT_TYPES[name], 0)
    return lambda b: zero


class Recipe:
    """A set-up list of variables: their types, and a struct that packs them."""

    def __init__(self, recipe_id: int, names: list[str], types: list[str]):
        self.id = recipe_id
        self.names = names
        self.types = types
        self.struct = struct.Struct(">" + "".join(FORMATS[t] for t in types))
        self._vector = [t.startswith("VECTOR") for t in types]

    def pack(self, values: list[Any]) -> bytes:
        flat: list[Any] = []
        for v, is_vector in zip(values, self._vector):
            if is_vector:
                flat.extend(v)
            else:
                flat.append(v)
        return self.struct.pack(*flat)

    def unpack(self, payload: bytes) -> dict[str, Any]:
        flat = list(self.struct.unpack(payload))
        out: dict[str, Any] = {}
        for name, fmt_type in zip(self.names, self.types):
            n = int(FORMATS[fmt_type][:-1]) if FORMATS[fmt_type][:-1] else 1
            out[name] = tuple(flat[:n]) if n > 1 else flat[0]
            del flat[:n]
        return out
