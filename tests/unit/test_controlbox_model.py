"""The emulated control box without sockets: the kinematic model and the emulation of
ur_rtde's control script, driven in virtual time (the clock is a variable)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from fluidsense.common.errors import CommandError, SafetyError
from fluidsense.simulator.controlbox.box import ControlBox, IdleProgram, RuntimeState
from fluidsense.simulator.controlbox.config import AnalogScale, ControlBoxConfig
from fluidsense.simulator.controlbox.kinematic import KinematicModel
from fluidsense.simulator.controlbox.model import AnalogDomain, RobotMode, SafetyMode
from fluidsense.simulator.controlbox.motion import LineMove, Trapezoid
from fluidsense.simulator.controlbox.urscript import RtdeControlScript, split_programs

START = (0.3, -0.2, 0.4, 0.0, 3.1416, 0.0)


def run_until(model: KinematicModel, t_end: float, dt: float = 0.002) -> list[tuple]:
    poses = []
    t = model.t
    while t < t_end - 1e-12:
        t = min(t_end, t + dt)
        model.advance(t)
        poses.append(model.tcp_pose)
    return poses


# -- motion -----------------------------------------------------------------------------------------

def test_trapezoid_reaches_cruise_speed_on_a_long_path_and_not_on_a_short_one():
    long = Trapezoid(length=1.0, v=0.25, a=1.0)
    assert long.v_peak == pytest.approx(0.25)
    assert long.duration == pytest.approx(0.25 / 1.0 + 1.0 / 0.25)  # t_acc + L/v
    short = Trapezoid(length=0.01, v=0.25, a=1.0)
    assert short.v_peak == pytest.approx(math.sqrt(0.01 * 1.0))
    assert short.duration == pytest.approx(2 * math.sqrt(0.01 / 1.0))
    for prof in (long, short):
        assert prof.distance(prof.duration) == pytest.approx(prof.length)
        ts = np.linspace(0, prof.duration, 200)
        d = np.array([prof.distance(t) for t in ts])
        assert np.all(np.diff(d) >= -1e-12)
        assert max(prof.speed(t) for t in ts) <= prof.v + 1e-12


def test_line_move_stays_on_the_line_and_turns_about_one_axis():
    end = (0.5, 0.1, 0.2, 0.0, 3.1416, 0.3)
    move = LineMove(START, end, 0.2, 1.0)
    p0, p1 = np.array(START[:3]), np.array(end[:3])
    direction = (p1 - p0) / np.linalg.norm(p1 - p0)
    for tau in np.linspace(0, move.duration, 50):
        p = np.array(move.pose(tau)[:3])
        off_line = (p - p0) - np.dot(p - p0, direction) * direction
        assert np.linalg.norm(off_line) < 1e-12
    assert move.pose(move.duration) == end


def test_a_pure_rotation_uses_the_speed_as_rad_per_s():
    start = (*START[:3], 0.0, 0.0, 0.2)
    end = (*START[:3], 0.0, 0.0, 0.7)  # 0.5 rad about z
    move = LineMove(start, end, 0.5, 5.0)
    assert move.duration == pytest.approx(Trapezoid(0.5, 0.5, 5.0).duration)
    assert move.pose(move.duration) == end


# -- kinematic model ------------------------------------------------------------------------------

def test_move_l_arrives_exactly_at_its_duration():
    m = KinematicModel(initial_pose=START)
    target = (0.35, -0.15, 0.37, 0.0, 3.1416, 0.0)
    m.move_l(target, 0.25, 1.2)
    expected = Trapezoid(math.dist(START[:3], target[:3]), 0.25, 1.2).duration
    run_until(m, expected - 0.01)
    assert m.is_moving() and m.tcp_pose != target
    assert 0 < np.linalg.norm(m.tcp_speed[:3]) <= 0.25 + 1e-9
    run_until(m, expected + 0.002)
    assert not m.is_moving()
    assert m.tcp_pose == target and m.tcp_speed == (0.0,) * 6


def test_the_speed_slider_scales_time():
    full, half = KinematicModel(initial_pose=START), KinematicModel(initial_pose=START)
    half.speed_fraction = 0.5
    target = (0.4, -0.2, 0.4, 0.0, 3.1416, 0.0)
    for m in (full, half):
        m.move_l(target, 0.1, 1.0)
    duration = Trapezoid(0.1, 0.1, 1.0).duration
    run_until(full, duration + 0.002)
    run_until(half, duration + 0.002)
    assert not full.is_moving() and half.is_moving()
    assert half.tcp_pose[0] == pytest.approx(0.3 + 0.05, abs=0.01)  # about half way
    run_until(half, 2 * duration + 0.004)
    assert half.tcp_pose == target


def test_stop_decelerates_along_the_path_and_speed_l_keeps_its_velocity():
    m = KinematicModel(initial_pose=START)
    m.move_l((1.0, -0.2, 0.4, 0.0, 3.1416, 0.0), 0.5, 2.0)
    run_until(m, 1.0)  # cruising at 0.5 m/s
    x_stop = m.tcp_pose[0]
    m.stop(2.0)
    run_until(m, 2.0)
    assert not m.is_moving()
    # from 0.5 m/s at 2 m/s^2: 0.0625 m more
    assert m.tcp_pose[0] == pytest.approx(x_stop + 0.0625, abs=1e-6)
    m.speed_l((0.0, 0.1, 0.0, 0.0, 0.0, 0.0), 1.0)
    run_until(m, 4.0)
    assert m.is_moving() and m.tcp_speed[1] == pytest.approx(0.1)
    assert m.tcp_pose[1] == pytest.approx(-0.2 + 0.1 * 2.0 - 0.5 * 0.1 * 0.1, abs=1e-6)


def test_safety_stops_halt_the_arm_and_refuse_motion():
    m = KinematicModel(initial_pose=START)
    m.move_l((0.6, -0.2, 0.4, 0.0, 3.1416, 0.0), 0.25, 1.2)
    run_until(m, 0.3)
    m.protective_stop = True
    where = m.tcp_pose
    run_until(m, 1.0)
    assert m.tcp_pose == where and not m.is_moving()
    assert m.safety_mode == SafetyMode.PROTECTIVE_STOP and not m.may_move()
    with pytest.raises(SafetyError, match="PROTECTIVE_STOP"):
        m.move_l(START, 0.25, 1.2)
    m.protective_stop = False
    m.emergency_stop = True
    assert m.safety_mode == SafetyMode.ROBOT_EMERGENCY_STOP
    m.emergency_stop = False
    m.robot_mode = RobotMode.POWER_OFF
    with pytest.raises(SafetyError, match="POWER_OFF"):
        m.move_l(START, 0.25, 1.2)


def test_model_time_never_goes_back_and_bad_requests_are_refused():
    m = KinematicModel()
    m.advance(1.0)
    with pytest.raises(ValueError, match="back"):
        m.advance(0.5)
    with pytest.raises(CommandError):
        m.move_l(START, 0.0, 1.0)
    with pytest.raises(CommandError):
        m.speed_fraction = 1.5
    with pytest.raises(CommandError):
        m.analog_input(2)
    with pytest.raises(ValueError, match="6 finite"):
        m.move_l((0.0, 0.0, float("nan"), 0.0, 0.0, 0.0), 0.1, 1.0)


def test_analog_input_source_is_sampled_at_every_advance():
    calls = []

    def source(channel, domain, t):
        calls.append((channel, domain, t))
        return t + channel if domain == AnalogDomain.VOLTAGE else 0.004

    m = KinematicModel(analog_input_source=source)
    m.set_analog_input(1, domain=AnalogDomain.CURRENT)
    m.advance(0.25)
    assert m.analog_input(0).value == 0.25 and m.analog_input(1).value == 0.004
    assert (1, AnalogDomain.CURRENT, 0.25) in calls


def test_digital_outputs_follow_the_mask():
    m = KinematicModel()
    m.set_digital_outputs(0b1111, 0b0101)
    m.set_digital_outputs(0b0011, 0b0010)
    assert m.digital_outputs == 0b0110
    m.set_digital_outputs(1 << 20, 1 << 20)  # beyond the 18 bits the box has
    assert m.digital_outputs == 0b0110


# -- the box around the model ------------------------------------------------------------------------

class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def make_box(**config):
    clock = Clock()
    box = ControlBox(ControlBoxConfig(**config), KinematicModel(initial_pose=START), clock)
    return box, clock


def cycle(box, clock, n=1):
    for _ in range(n):
        clock.t += 0.002
        box.tick()


def test_rtde_inputs_set_outputs_through_masks_and_call_the_hook():
    box, clock = make_box(analog=AnalogScale(voltage_v=(0.0, 10.0), current_ma=(4.0, 20.0)))
    seen = []
    box.model.on_outputs_changed = lambda t: seen.append((t, box.model.digital_outputs))
    clock.t = 0.5
    box.write_inputs({"standard_digital_output_mask": 0b1000, "standard_digital_output": 0b1111})
    assert box.model.digital_outputs == 0b1000
    assert seen == [(0.5, 0b1000)]
    box.write_inputs({"tool_digital_output_mask": 0b10, "tool_digital_output": 0b10})
    assert box.model.digital_outputs == 0b1000 | (0b10 << 16)
    # analog: mask says which channel, type bit 1 = voltage, the value is a ratio of the range;
    # the unmasked channel's value is garbage (ur_rtde leaves it uninitialised)
    box.write_inputs({"standard_analog_output_mask": 0b10, "standard_analog_output_type": 0b10,
                      "standard_analog_output_0": 1e300, "standard_analog_output_1": 0.5})
    assert box.model.analog_output(1).value == pytest.approx(5.0)
    assert box.model.analog_output(0).value == 0.0
    box.write_inputs({"standard_analog_output_mask": 0b01, "standard_analog_output_type": 0,
                      "standard_analog_output_0": 0.25, "standard_analog_output_1": float("nan")})
    assert box.model.analog_output(0).value == pytest.approx(0.008)
    assert box.model.analog_output(0).domain == AnalogDomain.CURRENT
    assert box.rtde_analog_value(box.model.analog_output(0)) == pytest.approx(8.0)  # mA on RTDE
    assert box.analog_io_types() == 0b1011  # inputs in voltage (default), output 0 in current
    box.write_inputs({"speed_slider_mask": 1, "speed_slider_fraction": 0.3})
    assert box.model.speed_fraction == pytest.approx(0.3)
    box.write_inputs({"input_int_register_20": -5, "input_double_register_21": 4.5})
    assert box.registers.read("input_int_register_20") == -5
    assert box.registers.read("input_double_register_21") == 4.5


def test_status_bits_follow_program_and_safety():
    box, clock = make_box()
    assert box.robot_status_bits() == 0b01  # powered, no program
    box.run_program(IdleProgram("idle.urp"))
    cycle(box, clock)
    assert box.robot_status_bits() == 0b11
    assert box.safety_status_bits() == 0b1  # normal mode
    box.model.protective_stop = True
    cycle(box, clock)
    assert box.safety_status_bits() == (1 << 2) | (1 << 10)
    assert box.runtime_state == RuntimeState.STOPPED and box.robot_status_bits() == 0b01
    box.model.protective_stop = False
    box.model.emergency_stop = True
    assert box.safety_status_bits() == (1 << 6) | (1 << 7) | (1 << 10)
    assert not box.run_program(IdleProgram("idle.urp"))


# -- ur_rtde's control script, register by register -------------------------------------------------

def send(box, cmd, ints=(), doubles=()):
    """What RTDEControlInterface writes for one command."""
    values = {"input_int_register_0": cmd}
    values.update({f"input_int_register_{i + 1}": v for i, v in enumerate(ints)})
    values.update({f"input_double_register_{i}": v for i, v in enumerate(doubles)})
    box.write_inputs(values)


def state(box, offset=0):
    return box.registers.read(f"output_int_register_{offset}")


def started_script(**kw):
    box, clock = make_box()
    script = RtdeControlScript(**kw)
    assert box.run_program(script)
    return box, clock, script


def test_script_signals_ready_then_done_only_when_the_movel_has_arrived():
    box, clock, _ = started_script()
    assert state(box) == 1
    target = (0.35, -0.2, 0.4, 0.0, 3.1416, 0.0)
    send(box, 3, ints=[0], doubles=[*target, 0.25, 1.2])
    duration = Trapezoid(0.05, 0.25, 1.2).duration
    cycle(box, clock, int(duration / 0.002) - 5)
    assert state(box) == 1 and box.model.is_moving()  # still moving: not done
    cycle(box, clock, 10)
    assert state(box) == 2 and box.model.tcp_pose == target
    cycle(box, clock, 3)
    assert state(box) == 2  # done stays until the client clears the command
    send(box, 0)
    cycle(box, clock)
    assert state(box) == 1


def test_async_movel_reports_progress_and_stopl_ends_it():
    box, clock, _ = started_script()
    progress = lambda: box.registers.read("output_int_register_2")  # noqa: E731
    assert progress() & 0x8000 == 0  # no async operation yet
    send(box, 3, ints=[1], doubles=[0.8, -0.2, 0.4, 0.0, 3.1416, 0.0, 0.1, 1.0])
    cycle(box, clock)
    assert state(box) == 2 and box.model.is_moving()  # async: done at once
    running = progress()
    assert running & 0x8000 and (running >> 24) == 1  # running, operation id 1
    send(box, 0)
    cycle(box, clock, 100)
    x_before = box.model.tcp_pose[0]
    send(box, 33, ints=[0], doubles=[2.0])  # stopL(2.0), synchronous
    cycle(box, clock, 2)
    assert progress() & 0x8000 == 0  # stopping the move ends the async operation
    cycle(box, clock, 200)
    assert state(box) == 2 and not box.model.is_moving()
    assert x_before < box.model.tcp_pose[0] < 0.8


def test_upper_range_registers_shift_every_register_by_24():
    box, clock, script = started_script(int_offset=24, float_offset=24)
    assert state(box, 24) == 1 and state(box) == 0
    target = (0.31, -0.2, 0.4, 0.0, 3.1416, 0.0)
    box.write_inputs({"input_int_register_24": 3, "input_int_register_25": 0,
                      **{f"input_double_register_{24 + i}": v for i, v in enumerate([*target, 0.25, 1.2])}})
    cycle(box, clock, 100)
    assert state(box, 24) == 2 and box.model.tcp_pose == target


def test_register_offsets_are_read_from_the_uploaded_script():
    # ur_rtde injects the offsets after these comments (the value lands on the next line)
    source = ("def rtde_control():\n    global reg_offset_float = # float register offset\n24"
              "    global reg_offset_int = # int register offset\n24    global x = 0\n"
              "    textmsg(\"RTDE Control Script Loaded\")\nend\n")
    script = RtdeControlScript.from_source(source)
    assert (script.int_offset, script.float_offset) == (24, 24)
    assert RtdeControlScript.from_source(source.replace("\n24", "\n0")).int_offset == 0


def test_an_unsupported_command_stops_the_script():
    box, clock, _ = started_script()
    send(box, 11, doubles=[0.0] * 11)  # servoJ: no joint model
    cycle(box, clock)
    assert box.runtime_state == RuntimeState.STOPPED and box.program is None


def test_stop_script_ends_the_program_without_done():
    box, clock, _ = started_script()
    send(box, 255)
    cycle(box, clock)
    assert box.runtime_state == RuntimeState.STOPPED and state(box) == 1


def test_watchdog_stops_the_program_when_the_client_goes_quiet():
    box, clock, _ = started_script()
    send(box, 35, doubles=[10.0])
    cycle(box, clock, 2)
    send(box, 0)
    for _ in range(20):  # kicked every 40 ms: fine
        cycle(box, clock, 20)
        send(box, 0)
    assert box.runtime_state == RuntimeState.PLAYING
    cycle(box, clock, 60)  # 120 ms without an update
    assert box.runtime_state == RuntimeState.STOPPED


def test_pause_brakes_and_play_resumes_the_interrupted_move():
    box, clock, _ = started_script()
    target = (0.5, -0.2, 0.4, 0.0, 3.1416, 0.0)
    send(box, 3, ints=[0], doubles=[*target, 0.25, 1.2])
    cycle(box, clock, 100)
    assert box.pause_program()
    cycle(box, clock, 200)
    assert not box.model.is_moving() and box.model.tcp_pose != target
    assert box.resume_program()
    cycle(box, clock, 1000)
    assert box.model.tcp_pose == target and state(box) == 2


def test_the_script_port_splits_complete_programs():
    text = "def a():\n  if x:\n    y()\n  end\nend\ndef b():\n  pass\n"
    programs, rest = split_programs(text)
    assert [name for name, _ in programs] == ["a"]
    assert rest == "\ndef b():\n  pass\n"
    programs, rest = split_programs(rest + "end\n")
    assert [name for name, _ in programs] == ["b"] and rest.strip() == ""


def test_bad_sim_control_commands_are_answered_not_fatal():
    """The sim-control port's handler (what `fluidsense simcell`'s tests and benches send
    lines to): a command it cannot parse or does not know is answered with the error, and
    the box runs on as it was; a good one is answered with the box's state."""
    from fluidsense.simulator.controlbox import simcontrol

    box, clock = make_box()
    cycle(box, clock, 5)
    for line in ('{"cmd": "set", "protective_stop": "maybe"}', '{"cmd": "teleport"}', "not json"):
        reply = simcontrol.handle(box, line)
        assert reply["ok"] is False and reply["error"].startswith("bad command"), reply
    state = simcontrol.handle(box, '{"cmd": "state", "id": 7}')
    assert state["ok"] is True and state["id"] == 7 and state["state"]["robot_mode"] == "RUNNING", state
