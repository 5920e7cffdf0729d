"""Programs sent to the script port (30003), and the emulation of ur_rtde's control script.

The emulator does not interpret URScript. It recognises the control script that ur_rtde
1.6.5's ``RTDEControlInterface`` uploads and runs an equivalent of its main loop: the
same command ids, argument registers, handshake and async progress register, with the
motions done by the model. Any other program is logged and not run.

The handshake (script ``rtde_control``, main loop, one iteration per controller cycle):
the client writes a command id to ``input_int_register_0`` and its arguments to
``input_double_register_0..`` / ``input_int_register_1..``; the script processes it and
sets ``output_int_register_0`` to 2 (done); the client then writes 0 and the script
answers 1 (ready). Real-time commands (speedL, servoJ, ...) get 1 at once. Register
numbers shift by 24 when the client uses the upper register range.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Callable

from fluidsense.common.errors import CommandError, SafetyError
from fluidsense.simulator.controlbox.box import ControlBox, Program, ProgramError
from fluidsense.simulator.controlbox.motion import Pose
from fluidsense.simulator.controlbox.watchdog import WatchdogProgram
from scipy.spatial.transform import Rotation

log = logging.getLogger(__name__)

READY, DONE = 1, 2
STOP_SCRIPT = 255
#: commands the script handles every cycle and answers with READY (no DONE)
REALTIME = frozenset({6, 9, 10, 11, 24, 25, 26, 27, 38, 58, 66, 67, 68, 69, 70, 71})
#: controller cycle on an e-Series (s): what get_steptime() returns
STEP_TIME = 0.002

COMMAND_NAMES = {
    1: "movej", 2: "movej_ik", 3: "movel", 4: "movel_fk", 6: "force_mode", 7: "force_mode_stop",
    8: "zero_ftsensor", 9: "speedj", 10: "speedl", 11: "servoj", 12: "servoc", 15: "speed_stop",
    16: "servo_stop", 17: "set_payload", 18: "teach_mode", 19: "end_teach_mode",
    20: "force_mode_set_damping", 21: "force_mode_set_gain_scaling", 24: "servol", 25: "tool_contact",
    26: "get_steptime", 27: "get_actual_joint_positions_history", 28: "get_target_waypoint",
    29: "set_tcp", 30: "get_inverse_kin_args", 31: "protective_stop", 33: "stopl", 34: "stopj",
    35: "set_watchdog", 36: "is_pose_within_safety_limits", 37: "is_joints_within_safety_limits",
    38: "get_joint_torques", 39: "pose_trans", 40: "get_tcp_offset", 41: "start_jog", 42: "stop_jog",
    43: "get_forward_kinematics_default", 44: "get_forward_kinematics_args", 45: "move_path",
    46: "get_inverse_kin_default", 47: "is_steady", 51: "move_until_contact", 52: "freedrive_mode",
    53: "end_freedrive_mode", 54: "get_freedrive_status", 56: "ft_rtde_input_enable",
    57: "enable_external_ft_sensor", 58: "get_actual_tool_flange_pose", 59: "set_gravity",
    60: "get_inverse_kin_has_solution_default", 61: "get_inverse_kin_has_solution_args",
    62: "start_contact_detection", 63: "stop_contact_detection", 64: "read_contact_detection",
    65: "set_target_payload", 66: "direct_torque", 67: "get_mass_matrix",
    68: "get_coriolis_and_centrifugal_torques", 69: "get_target_joint_accelerations",
    70: "get_jacobian", 71: "get_jacobian_time_derivative", 255: "stop_script",
}
#: accepted and ignored: they configure things the kinematic arm does not have
NO_OPS = frozenset({8, 17, 18, 19, 20, 21, 56, 57, 59, 65, 66, 67, 68, 69, 70, 71})

_OFFSET = {kind: re.compile(rf"reg_offset_{kind}\s*=\s*# {kind} register offset\s*\n\s*(\d+)")
           for kind in ("float", "int")}

Wait = Callable[[], bool]


def _name(cmd: int) -> str:
    return COMMAND_NAMES.get(cmd, "unknown")


class RtdeControlScript(Program):
    """ur_rtde 1.6.5's ``rtde_control`` script, command by command."""

    name = "rtde_control"

    def __init__(self, int_offset: int = 0, float_offset: int = 0):
        self.int_offset = int_offset
        self.float_offset = float_offset
        self.box: ControlBox | None = None
        self._executing = False
        self._blocking: Wait | None = None
        self._move_thread = False
        self._stop_thread = False
        #: the motion to pick up again after a pause: ("line", pose, v, a) or ("speed", xd, a)
        self._motion: tuple | None = None
        self._async_wr_count = 0
        self._async_op_id = 0
        #: (watched input variable, minimum update frequency in Hz, model time armed)
        self._watchdog: tuple[str, float, float] | None = None
        self._tcp_offset: Pose = (0.0,) * 6  # type: ignore[assignment]

    @classmethod
    def from_source(cls, text: str) -> RtdeControlScript:
        offsets = {kind: int(m.group(1)) if (m := rx.search(text)) else 0 for kind, rx in _OFFSET.items()}
        return cls(int_offset=offsets["int"], float_offset=offsets["float"])

    # -- registers ---------------------------------------------------------------------------
    def _in_int(self, i: int) -> int:
        return self.box.registers.ints["input"][i + self.int_offset]

    def _in_float(self, i: int) -> float:
        return self.box.registers.doubles["input"][i + self.float_offset]

    def _in_pose(self, i: int) -> Pose:
        return tuple(self._in_float(i + k) for k in range(6))  # type: ignore[return-value]

    def _out_int(self, i: int, value: int) -> None:
        self.box.registers.write(f"output_int_register_{i + self.int_offset}", value)

    def _out_float(self, i: int, value: float) -> None:
        self.box.registers.doubles["output"][i + self.float_offset] = float(value)

    def _out_pose(self, i: int, pose) -> None:
        for k, v in enumerate(pose):
            self._out_float(i + k, v)

    def _ready(self) -> None:
        self._out_int(0, READY)

    def _done(self) -> None:
        self._out_int(0, DONE)

    def _async_progress(self, value: int) -> None:
        """output_int_register_2: bits 24-30 operation id, 16-23 write count, 15 running,
        0-14 progress (the script's write_async_progress_register)."""
        self._async_wr_count = 0 if self._async_wr_count >= 127 else self._async_wr_count + 1
        if value == 0:
            self._async_op_id = 0 if self._async_op_id >= 127 else self._async_op_id + 1
        reg = self._async_wr_count * 65536 + self._async_op_id * 16777216
        if value >= 0:
            reg += min(value, 32767) + 32768
        self._out_int(2, reg)

    # -- program life --------------------------------------------------------------------------
    def start(self, box: ControlBox) -> None:
        self.box = box
        log.info("rtde_control script running (register offsets int %d, float %d)",
                 self.int_offset, self.float_offset)
        self._async_progress(-1)
        self._ready()

    def step(self, box: ControlBox) -> bool:
        self._run_threads()
        self._check_watchdog()
        if self._blocking is not None:
            if not self._blocking():
                return True
            self._blocking = None
            self._motion = None
            self._done()
            return True
        cmd = self._in_int(0)
        if cmd in REALTIME:
            self._process(cmd)
            self._ready()
            return True
        if cmd == 0:
            self._executing = False
            self._ready()
            return True
        if self._executing:
            return True
        self._executing = True
        return self._process(cmd)

    def stopped(self, box: ControlBox) -> None:
        self._blocking = None
        self._move_thread = self._stop_thread = False

    def paused(self, box: ControlBox) -> None:
        log.debug("paused with motion %s", self._motion)

    def resumed(self, box: ControlBox) -> None:
        motion, model = self._motion, box.model
        if motion is None:
            return
        try:
            if motion[0] == "line":
                model.move_l(*motion[1:])
            else:
                model.speed_l(*motion[1:])
        except SafetyError as exc:
            log.warning("could not resume %s: %s", motion[0], exc)

    # -- the background threads of the script --------------------------------------------------
    def _run_threads(self) -> None:
        moving = self.box.model.is_moving()
        if self._move_thread and not moving:
            self._move_thread = False
            self._motion = None
            self._async_progress(-1)
        if self._stop_thread and not moving:
            self._stop_thread = False
            self._async_progress(-1)

    def _check_watchdog(self) -> None:
        if self._watchdog is None:
            return
        name, hz, armed_at = self._watchdog
        period = 1.0 / hz
        last = max(armed_at, self.box.input_times.get(name, -math.inf))
        if self.box.model.t - last > period:
            raise ProgramError(f"RTDE watchdog: {name} not updated for more than {period:.3f} s")

    def _stop_async_move(self) -> None:
        if self._move_thread:
            log.debug("stopping async movement")
            self._move_thread = False
            self._motion = None
            self._async_progress(-1)

    # -- commands ------------------------------------------------------------------------------------
    def _process(self, cmd: int) -> bool:
        if cmd == STOP_SCRIPT:
            log.info("received stop script")
            return False
        log.debug("command %d (%s)", cmd, _name(cmd))
        handler = _HANDLERS.get(cmd)
        if handler is None and cmd not in NO_OPS:
            raise ProgramError(f"command {cmd} ({_name(cmd)}) is not emulated")
        try:
            wait = handler(self) if handler is not None else None
        except (SafetyError, CommandError, ValueError) as exc:
            raise ProgramError(f"{_name(cmd)}: {exc}") from exc
        if wait is None:
            self._done()
        else:
            self._blocking = wait
        return True

    def _still(self) -> Wait:
        model = self.box.model
        return lambda: not model.is_moving()

    def _line(self, asynchronous: bool) -> Wait | None:
        pose, speed, acc = self._in_pose(0), self._in_float(6), self._in_float(7)
        self._stop_async_move()
        self.box.model.move_l(pose, speed, acc)
        self._motion = ("line", pose, speed, acc)
        if asynchronous:
            self._move_thread = True
            self._async_progress(0)
            return None
        return self._still()

    def _movel(self) -> Wait | None:
        return self._line(self._in_int(1) == 1)

    def _stopl(self) -> Wait | None:
        """exec_stopl_stopj: restart a running async stop, else stop the async move."""
        decel, asynchronous = self._in_float(0), self._in_int(1) == 1
        stop_move = True
        if self._stop_thread:
            stop_move = False
            self._stop_thread = False
            self._async_progress(-1)
        if stop_move:
            self._stop_async_move()
        self._motion = None
        self.box.model.stop(decel)
        if asynchronous:
            self._stop_thread = True
            self._async_progress(0)
            return None
        return self._still()

    def _speedl(self) -> None:
        xd, acc = self._in_pose(0), self._in_float(6)
        self.box.model.speed_l(xd, acc)
        self._motion = ("speed", xd, acc)

    def _stop_with(self, decel: float) -> Wait:
        self._motion = None
        self.box.model.stop(decel)
        return self._still()

    def _set_watchdog(self) -> None:
        hz = self._in_float(0)
        if not hz > 0:
            raise CommandError(f"watchdog frequency must be > 0, got {hz}")
        # the script watches input_int_register_0, or _24 in the upper range
        name = f"input_int_register_{24 if self.int_offset == 24 else 0}"
        self._watchdog = (name, hz, self.box.model.t)
        log.info("RTDE watchdog on %s at %.1f Hz", name, hz)

    def _protective_stop(self) -> None:
        self.box.model.protective_stop = True

    def _pose_trans(self) -> None:
        p_from, p_to = self._in_pose(0), self._in_pose(6)
        r_from = Rotation.from_rotvec(p_from[3:])
        xyz = [a + b for a, b in zip(p_from[:3], r_from.apply(p_to[:3]))]
        rot = (r_from * Rotation.from_rotvec(p_to[3:])).as_rotvec()
        self._out_pose(0, [*xyz, *rot])

    def _set_tcp(self) -> None:
        self._tcp_offset = self._in_pose(0)


_HANDLERS: dict[int, Callable[[RtdeControlScript], Wait | None]] = {
    # moveJ_IK has no joint space here: the TCP goes to the pose along a line, with the
    # joint speed and acceleration taken as m/s and m/s^2 (documented approximation)
    2: lambda s: s._line(s._in_int(1) == 1),
    3: RtdeControlScript._movel,
    7: lambda s: s._stop_with(10.0),
    10: RtdeControlScript._speedl,
    15: lambda s: s._stop_with(s._in_float(0)),
    16: lambda s: s._stop_with(s._in_float(0)),
    25: lambda s: s._out_int(1, 0),  # tool_contact: no contact
    26: lambda s: s._out_float(0, STEP_TIME),
    27: lambda s: s._out_pose(0, [0.0] * 6),  # no joint model
    28: lambda s: s._out_pose(0, s.box.model.target_pose),
    29: RtdeControlScript._set_tcp,
    31: RtdeControlScript._protective_stop,
    33: RtdeControlScript._stopl,
    34: RtdeControlScript._stopl,
    35: RtdeControlScript._set_watchdog,
    36: lambda s: s._out_int(1, 1),
    37: lambda s: s._out_int(1, 1),
    38: lambda s: s._out_pose(0, [0.0] * 6),  # no joint model
    39: RtdeControlScript._pose_trans,
    40: lambda s: s._out_pose(0, s._tcp_offset),
    42: lambda s: s._stop_with(1.2),
    43: lambda s: s._out_pose(0, s.box.model.tcp_pose),
    47: lambda s: s._out_int(1, 0 if s.box.model.is_moving() else 1),
    54: lambda s: s._out_int(1, 0),  # freedrive is never active
    58: lambda s: s._out_pose(0, s.box.model.tcp_pose),
}


# -- the script port -----------------------------------------------------------------------------------
_PROGRAM = re.compile(r"^(def|sec)[ \t]+(\w+)[ \t]*\([^)]*\)[ \t]*:.*?^end[ \t]*\r?$", re.M | re.S)


def split_programs(buffer: str) -> tuple[list[tuple[str, str]], str]:
    """Complete top-level programs ``(name, source)`` in ``buffer``, and the rest.

    A program ends at the first ``end`` in column 0 (ur_rtde's script indents every
    nested block). Text outside programs is returned in the rest until a program
    starts after it."""
    programs: list[tuple[str, str]] = []
    pos = 0
    for m in _PROGRAM.finditer(buffer):
        stray = buffer[pos:m.start()].strip()
        if stray:
            programs.append(("<statements>", stray))
        programs.append((m.group(2), m.group(0)))
        pos = m.end()
    return programs, buffer[pos:]


def program_from_source(name: str, source: str) -> Program | None:
    """The emulated program for ``source``, or None when it cannot be run here."""
    if name == "rtde_control" and "RTDE Control Script" in source:
        return RtdeControlScript.from_source(source)
    if name == WatchdogProgram.name:
        return WatchdogProgram.from_source(source)
    return None
