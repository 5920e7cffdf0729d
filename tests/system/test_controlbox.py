"""The emulated UR control box against the real clients: ur_rtde 1.6.5's Receive, IO and
Control interfaces and pymodbus, each in its own process, each test on its own
127.0.0.x address (ur_rtde's ports are fixed). Every client call and every wait has a
timeout; nothing waits on the wall clock for timing to pass.
"""

from __future__ import annotations

import asyncio
import math
import signal
import socket
import struct
import time

import numpy as np
import pytest
from fluidsense.common.errors import LinkLostError
from fluidsense.simulator.controlbox.process import EmulatorProcess
from pymodbus.client import AsyncModbusTcpClient
from support.controlbox import MODBUS_PORT, PORTS, RawRtde, free_host
from support.ur_client import UrClient

START = [0.3, -0.2, 0.4, 0.0, 3.1416, 0.0]  # KinematicModel's default pose


@pytest.fixture
def clients():
    made: list[UrClient] = []

    def connect(kind: str, host: str, *args) -> UrClient:
        client = UrClient(kind, host, *args, timeout_s=20)
        made.append(client)
        return client

    yield connect
    for client in made:
        try:
            client.close(timeout_s=10)
        finally:
            client.kill()


def eventually(fn, timeout_s: float = 10.0, what: str = "condition"):
    """Poll ``fn`` until it returns something truthy."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = fn()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"{what} not reached within {timeout_s} s (last: {value!r})")
        time.sleep(0.01)


class Dashboard:
    def __init__(self, host: str):
        self.sock = socket.create_connection((host, 29999), timeout=10)
        self.file = self.sock.makefile("r")
        self.greeting = self.file.readline().strip()

    def __call__(self, command: str) -> str:
        self.sock.sendall((command + "\n").encode())
        return self.file.readline().strip()

    def close(self) -> None:
        self.file.close()
        self.sock.close()


def modbus(host: str, body):
    """Run ``await body(client)`` with a connected pymodbus client."""
    async def main():
        client = AsyncModbusTcpClient(host, port=MODBUS_PORT, timeout=5, retries=1)
        assert await client.connect(), "modbus connect failed"
        try:
            return await body(client)
        finally:
            client.close()
    return asyncio.run(asyncio.wait_for(main(), 30))


async def regs(client, address: int, count: int = 1) -> list[int]:
    reply = await client.read_holding_registers(address, count=count)
    assert not reply.isError(), reply
    return reply.registers


# -- RTDE Receive ----------------------------------------------------------------------------------

def test_receive_reads_pose_io_analog_inputs_and_modes(start_box, clients):
    box = start_box()
    box.set(analog_input={"channel": 0, "value": 4.5, "domain": "VOLTAGE"})
    box.set(analog_input={"channel": 1, "value": 0.012, "domain": "CURRENT"})
    box.set(digital_inputs={"mask": 0xFF, "bits": 0b10010})
    box.set(tcp_pose=[0.25, -0.3, 0.15, 0.1, 3.0, -0.2])
    r = clients("receive", box.host)
    eventually(lambda: r.getActualTCPPose() == [0.25, -0.3, 0.15, 0.1, 3.0, -0.2], what="pose")
    assert r.getStandardAnalogInput0() == pytest.approx(4.5)
    assert r.getStandardAnalogInput1() == pytest.approx(12.0)  # RTDE reports mA
    assert r.getActualDigitalInputBits() == 0b10010
    assert r.getDigitalInState(4) and not r.getDigitalInState(0)
    assert r.getRobotMode() == 7 and r.getSafetyMode() == 1
    assert r.getRuntimeState() == 1  # no program
    assert r.getRobotStatus() == 1  # powered, no program running
    assert not r.isProtectiveStopped() and not r.isEmergencyStopped()
    t0 = r.getTimestamp()
    eventually(lambda: r.getTimestamp() > t0, what="timestamp advancing")


def test_receive_sees_protective_and_emergency_stops(start_box, clients):
    box = start_box()
    r = clients("receive", box.host)
    box.set(protective_stop=True)
    eventually(lambda: r.isProtectiveStopped(), what="protective stop")
    assert r.getSafetyMode() == 3
    assert r.getSafetyStatusBits() & (1 << 2)
    box.set(protective_stop=False, emergency_stop=True)
    eventually(lambda: r.isEmergencyStopped(), what="emergency stop")
    assert not r.isProtectiveStopped() and r.getSafetyMode() == 7


# -- RTDE IO ----------------------------------------------------------------------------------------

def test_io_outputs_reach_the_model_and_are_read_back_by_receive_and_modbus(start_box, clients):
    box = start_box()
    io = clients("io", box.host)
    r = clients("receive", box.host)
    assert io.setStandardDigitalOut(3, True)
    assert io.setToolDigitalOut(1, True)
    assert io.setAnalogOutputVoltage(1, 0.5)  # half of 0-10 V
    assert io.setAnalogOutputCurrent(0, 0.25)  # a quarter of 4-20 mA
    assert io.setSpeedSlider(0.5)
    assert io.setInputIntRegister(20, -42)
    state = box.wait_for(lambda s: s["speed_fraction"] == 0.5 and s["input_int_registers"][20] == -42,
                         what="IO writes in the model")
    assert state["digital_outputs"] == (1 << 3) | (1 << 17)
    assert state["analog_outputs"][1] == {"value": pytest.approx(5.0), "domain": "VOLTAGE"}
    assert state["analog_outputs"][0] == {"value": pytest.approx(0.008), "domain": "CURRENT"}

    # the receive client may still be reading packages sent before the last write was
    # applied (a busy machine): wait for the one sent after the speed slider, the last of them
    eventually(lambda: r.getSpeedScaling() == pytest.approx(0.5), what="speed slider on RTDE")
    assert r.getActualDigitalOutputBits() == (1 << 3) | (1 << 17)
    assert r.getStandardAnalogOutput1() == pytest.approx(5.0)
    assert r.getStandardAnalogOutput0() == pytest.approx(8.0)  # mA
    assert r.getSpeedScaling() == pytest.approx(0.5)

    async def read(client):
        return await regs(client, 0, 20)
    registers = modbus(box.host, read)
    assert registers[1] == (1 << 3) | (1 << 9)  # standard bit 3, tool bit 1 -> register bit 9
    assert registers[16:20] == [round(0.25 * 65535), 0, round(0.5 * 65535), 1]

    assert io.setStandardDigitalOut(3, False)
    eventually(lambda: not r.getDigitalOutState(3), what="digital out 3 off")


# -- RTDE Control -----------------------------------------------------------------------------------

def on_line(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Largest distance of ``points`` from the segment a-b's line."""
    d = (b - a) / np.linalg.norm(b - a)
    rel = points - a
    return float(np.max(np.linalg.norm(rel - np.outer(rel @ d, d), axis=1)))


def test_control_movel_goes_straight_to_the_target_and_reports_done_on_arrival(start_box, clients):
    box = start_box()
    c = clients("control", box.host)
    r = clients("receive", box.host)
    assert c.isProgramRunning()
    target = [0.38, -0.25, 0.35, 0.0, 3.1416, 0.0]
    speed = 0.1
    c.start_call("moveL", target, speed, 0.5)
    samples = []
    state = box.wait_for(lambda s: s["moving"], what="arm moving")
    while state["moving"]:
        samples.append(state)
        state = box.state()
    assert c.finish_call() is True  # returned only after the arm stopped moving
    assert state["tcp_pose"] == pytest.approx(target, abs=1e-12)
    # the receive client holds the newest package it has read: on a loaded machine one sent just
    # before the arrival may still be it, so wait for the package after (500 Hz)
    eventually(lambda: r.getActualTCPPose() == pytest.approx(target, abs=1e-12), 10.0, "the arrival in RTDE")
    points = np.array([s["tcp_pose"][:3] for s in samples])
    assert len(points) > 5
    assert on_line(points, np.array(START[:3]), np.array(target[:3])) < 1e-9
    assert max(np.linalg.norm(s["tcp_speed"][:3]) for s in samples) <= speed + 1e-9
    assert all(s["tcp_pose"][3:] == pytest.approx(START[3:]) for s in samples)


def test_control_async_movel_is_stopped_by_stopl(start_box, clients):
    box = start_box()
    c = clients("control", box.host)
    target = [0.3, 0.2, 0.4, 0.0, 3.1416, 0.0]  # 0.4 m at 0.05 m/s: 8 s
    assert c.moveL(target, 0.05, 0.5, True) is True
    box.wait_for(lambda s: s["moving"] and s["tcp_pose"][1] > -0.19, what="async move under way")
    assert c.getAsyncOperationProgressEx()["running"]
    c.stopL(1.0)
    state = box.state()
    assert not state["moving"]  # stopL returns once the arm is still
    assert -0.19 < state["tcp_pose"][1] < 0.2
    assert not c.getAsyncOperationProgressEx()["running"]
    assert c.isProgramRunning()  # ready for the next command
    assert c.moveL(START, 0.25, 1.2) is True
    assert box.state()["tcp_pose"] == pytest.approx(START, abs=1e-12)


def test_control_refuses_motion_while_protective_stopped_and_recovers_after_unlock(start_box, clients):
    box = start_box("--unlock-delay", "0")
    c = clients("control", box.host)
    r = clients("receive", box.host)
    box.set(protective_stop=True)
    eventually(lambda: r.isProtectiveStopped(), what="protective stop on RTDE")
    target = [0.32, -0.2, 0.4, 0.0, 3.1416, 0.0]
    assert c.moveL(target, 0.25, 1.2) is False
    state = box.state()
    assert state["tcp_pose"] == pytest.approx(START) and state["runtime_state"] == "STOPPED"
    assert not c.isProgramRunning()

    dash = Dashboard(box.host)
    try:
        assert dash("unlock protective stop") == "Protective stop releasing"
    finally:
        dash.close()
    eventually(lambda: not r.isProtectiveStopped(), what="protective stop released")
    assert c.reuploadScript() is True
    # reuploadScript does not wait for the program to start (on a robot either)
    eventually(lambda: c.isProgramRunning(), what="control script running again")
    assert c.moveL(target, 0.25, 1.2) is True
    assert box.state()["tcp_pose"] == pytest.approx(target, abs=1e-12)


def test_control_speedl_speedstop_and_an_unsupported_command(start_box, clients):
    box = start_box()
    c = clients("control", box.host)
    assert c.speedL([0.0, 0.05, 0.0, 0.0, 0.0, 0.0], 0.5, 0.0) is True
    state = box.wait_for(lambda s: s["tcp_speed"][1] == pytest.approx(0.05), what="cruising at 0.05 m/s")
    assert state["moving"] and state["tcp_pose"][1] > START[1]
    assert c.speedStop(1.0) is True
    state = box.state()
    assert not state["moving"] and state["tcp_speed"] == [0.0] * 6
    # no joint space in the kinematic arm: the script fails as a real one would on an error
    assert c.moveJ([0.0, -1.57, 1.57, -1.57, -1.57, 0.0], 1.0, 1.0) is False
    assert box.state()["runtime_state"] == "STOPPED" and not c.isProgramRunning()
    assert "command 1 (movej) is not emulated" in box.log()


def test_clients_on_the_upper_register_range_and_a_custom_receive_recipe(start_box, clients):
    box = start_box()
    flags = 1 | 8  # FLAG_UPLOAD_SCRIPT | FLAG_UPPER_RANGE_REGISTERS
    c = clients("control", box.host, -1.0, flags)
    io = clients("io", box.host, False, True)  # use_upper_range_registers
    r = clients("receive", box.host, 125.0, ["timestamp", "actual_TCP_pose", "input_int_register_44"])
    state = box.state()
    assert state["output_int_registers"][24] == 1 and state["output_int_registers"][0] == 0
    target = [0.31, -0.21, 0.4, 0.0, 3.1416, 0.0]
    assert c.moveL(target, 0.25, 1.2) is True
    assert box.state()["tcp_pose"] == pytest.approx(target, abs=1e-12)
    eventually(lambda: r.getActualTCPPose() == pytest.approx(target, abs=1e-12), what="pose at 125 Hz")
    assert io.setInputIntRegister(44, 7)
    box.wait_for(lambda s: s["input_int_registers"][44] == 7, what="upper range input register")


def test_a_protective_stop_during_a_blocking_movel_makes_it_fail(start_box, clients):
    box = start_box()
    c = clients("control", box.host)
    target = [0.3, 0.1, 0.4, 0.0, 3.1416, 0.0]
    c.start_call("moveL", target, 0.05, 0.5)
    box.wait_for(lambda s: s["moving"], what="arm moving")
    box.set(protective_stop=True)
    assert c.finish_call() is False
    state = box.state()
    assert not state["moving"] and state["tcp_pose"][1] < 0.1


# -- Modbus ------------------------------------------------------------------------------------------

def test_modbus_set_and_clear_masks_and_general_purpose_registers(start_box):
    box = start_box()

    async def body(client):
        assert not (await client.write_register(2, 0b1010_0101)).isError()  # set mask
        after_set = (await regs(client, 1))[0]
        assert not (await client.write_register(3, 0b0000_0101)).isError()  # clear mask
        after_clear = (await regs(client, 1))[0]
        assert not (await client.write_register(1, 0)).isError()  # outputs written directly
        await client.write_register(2, 1 << 9)  # tool output 1
        tool = (await regs(client, 1))[0]
        await client.write_registers(130, [0, 65535, 1234])
        gp = await regs(client, 130, 3)
        refused = await client.write_register(0, 1)  # inputs are read-only
        return after_set, after_clear, tool, gp, refused

    after_set, after_clear, tool, gp, refused = modbus(box.host, body)
    assert after_set == 0b1010_0101 and after_clear == 0b1010_0000
    assert tool == 1 << 9
    assert box.state()["digital_outputs"] == 1 << 17  # tool output 1 in RTDE's bit order
    assert gp == [0, 65535, 1234]
    assert refused.isError() and refused.exception_code == 2  # illegal data address


def test_modbus_analog_raw_values_and_domains(start_box):
    box = start_box()
    box.set(analog_input={"channel": 0, "value": 2.5, "domain": "VOLTAGE"})
    box.set(analog_input={"channel": 1, "value": 0.012, "domain": "CURRENT"})

    async def body(client):
        inputs = await regs(client, 4, 4)
        await client.write_registers(16, [16384, 0])  # output 0: current, raw a quarter
        await client.write_register(19, 1)  # output 1: voltage
        await client.write_register(18, 65535)
        outputs = await regs(client, 16, 4)
        bad = await client.write_register(17, 7)  # not a domain
        return inputs, outputs, bad

    inputs, outputs, bad = modbus(box.host, body)
    assert inputs == [round(0.25 * 65535), 1, round(0.5 * 65535), 0]  # 2.5 of 10 V; 12 of 4-20 mA
    assert outputs == [16384, 0, 65535, 1]
    state = box.state()
    assert state["analog_outputs"][0] == {"value": pytest.approx(0.004 + 16384 / 65535 * 0.016), "domain": "CURRENT"}
    assert state["analog_outputs"][1] == {"value": pytest.approx(10.0), "domain": "VOLTAGE"}
    assert bad.isError()


def test_modbus_tcp_pose_wraps_negatives_and_shows_robot_and_safety_state(start_box):
    box = start_box()
    box.set(tcp_pose=[-0.1234, 0.5, -0.05, -1.5, 0.2, 3.0])

    async def read_state(client):
        return await regs(client, 400, 6), await regs(client, 258), await regs(client, 261, 2)

    pose, mode, stops = modbus(box.host, read_state)
    assert pose == [(-1234) & 0xFFFF, 5000, (-500) & 0xFFFF, (-1500) & 0xFFFF, 200, 3000]
    assert mode == [7] and stops == [0, 0]
    box.set(protective_stop=True)
    _, _, stops = modbus(box.host, read_state)
    assert stops == [1, 0]
    box.set(protective_stop=False, emergency_stop=True, robot_mode="NO_CONTROLLER")
    _, mode, stops = modbus(box.host, read_state)
    assert stops == [0, 1] and mode == [0xFFFF]  # -1 as uint16


# -- dashboard ---------------------------------------------------------------------------------------

def test_dashboard_answers_what_clients_ask(start_box):
    box = start_box()
    dash = Dashboard(box.host)
    try:
        assert dash.greeting == "Connected: Universal Robots Dashboard Server"
        assert dash("PolyscopeVersion").startswith("URSoftware 5.")
        assert dash("get serial number").isdigit()
        assert dash("is in remote control") == "true"
        assert dash("robotmode") == "Robotmode: RUNNING"
        assert dash("power off") == "Powering off"
        assert box.state()["robot_mode"] == "POWER_OFF"
        assert dash("play") == "Failed to execute: play"  # nothing loaded, no power
        assert dash("power on") == "Powering on"
        assert dash("robotmode") == "Robotmode: IDLE"
        assert dash("brake release") == "Brake releasing"
        assert box.state()["robot_mode"] == "RUNNING"
        assert dash("load /programs/pick.urp") == "Loading program: /programs/pick.urp"
        assert dash("get loaded program") == "Loaded program: /programs/pick.urp"
        assert dash("play") == "Starting program"
        assert dash("running") == "Program running: true"
        assert dash("programState").startswith("PLAYING")
        assert dash("stop") == "Stopped"
        assert dash("running") == "Program running: false"
        box.set(protective_stop=True)
        assert dash("safetystatus") == "Safetystatus: PROTECTIVE_STOP"
        assert dash("unlock protective stop").startswith("Cannot unlock protective stop until 5s")
        assert box.state()["protective_stop"]
        assert dash("hello robot") == "could not understand: 'hello robot'"
        assert dash("quit") == "Disconnected"
        assert dash.file.readline() == ""  # closed by the box
    finally:
        dash.close()


def test_dashboard_shutdown_ends_the_emulator_cleanly(start_box):
    box = start_box()
    dash = Dashboard(box.host)
    try:
        assert dash("shutdown") == "Shutting down"
        assert box.proc.wait(timeout=10) == 0
    finally:
        dash.close()


# -- RTDE protocol details (a raw socket) ---------------------------------------------------------------


def test_rtde_handshake_data_and_refused_variables(start_box):
    box = start_box()
    a, b = RawRtde(box.host), RawRtde(box.host)
    try:
        assert a.ask("V", struct.pack(">H", 2)) == b"\x01"
        assert a.ask("V", struct.pack(">H", 7)) == b"\x00"  # only version 2
        assert struct.unpack(">IIII", a.ask("v")) == (5, 11, 1, 108318)
        a.send("M", b"\x05hello\x04test\x01")  # a client text message is only logged
        refused = a.ask("O", struct.pack(">d", 125.0) + b"timestamp,no_such_variable")
        assert refused == b"\x00DOUBLE,NOT_FOUND"
        accepted = a.ask("O", struct.pack(">d", 125.0) + b"timestamp,actual_TCP_pose,runtime_state,")
        assert accepted[0] >= 1 and accepted[1:] == b"DOUBLE,VECTOR6D,UINT32"

        assert a.ask("I", b"input_int_register_30,input_double_register_30") == b"\x01INT32,DOUBLE"
        assert b.ask("I", b"input_int_register_30") == b"\x00IN_USE"  # a has it
        assert b.ask("I", b"speed_slider_maskk") == b"\x00NOT_FOUND"
        a.send("U", b"\x01" + struct.pack(">id", 1234, -2.5))
        box.wait_for(lambda s: s["input_int_registers"][30] == 1234, what="register write")
        assert box.state()["input_double_registers"][30] == -2.5

        assert a.ask("S") == b"\x01"
        stamps = []
        while len(stamps) < 5:
            kind, body = a.recv()
            if kind == "U":
                assert body[0] == accepted[0]
                t, *pose, runtime = struct.unpack(">d6dI", body[1:])
                assert pose == pytest.approx(START) and runtime == 1
                stamps.append(t)
        assert stamps == sorted(set(stamps))
        assert a.ask("P") == b"\x01"
    finally:
        a.close()
    # a's input goes free with its connection
    eventually(lambda: b.ask("I", b"input_int_register_30") == b"\x01INT32", what="input released")
    b.close()


# -- the process ------------------------------------------------------------------------------------------

def test_sigterm_closes_every_port_and_exits_0(start_box, clients):
    box = start_box()
    r = clients("receive", box.host)
    assert r.isConnected()
    assert box.stop() == 0
    for port in PORTS:
        with pytest.raises(ConnectionRefusedError):
            socket.create_connection((box.host, port), timeout=5).close()
    eventually(lambda: not r.isConnected(), what="client sees the box gone")


def _take_dashboard_port() -> socket.socket:
    """A listening socket on some free host's dashboard port. SO_REUSEADDR because an earlier
    box on that host may have left connections in TIME_WAIT there (a plain bind fails on them,
    the emulator's does not); a retry because another worker may take the host in between."""
    for _ in range(20):
        host = free_host()
        taken = socket.socket()
        taken.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            taken.bind((host, 29999))
            taken.listen()
        except OSError:
            taken.close()
            continue
        return taken
    raise AssertionError("no host whose dashboard port this test could take")


def test_a_port_in_use_stops_the_emulator_before_ready():
    with _take_dashboard_port() as taken:
        host = taken.getsockname()[0]
        box = EmulatorProcess(host, modbus_port=MODBUS_PORT)
        with pytest.raises(LinkLostError, match="exited"):
            box.start(timeout_s=30)
        assert box.proc.returncode == 2
        assert "DashboardServer cannot listen" in box.log()
        box.__exit__(None, None, None)


def test_a_model_factory_backs_the_box(start_box, clients):
    box = start_box(model="tests.support.controlbox_models:loopback")
    io = clients("io", box.host)
    r = clients("receive", box.host)
    assert io.setStandardDigitalOut(5, True)
    assert io.setAnalogOutputVoltage(0, 0.3)
    # the model's on_outputs_changed wires the outputs back to the inputs...
    eventually(lambda: r.getDigitalInState(5), what="output 5 looped back to input 5")
    # ...and its analog_input_source reads the analog output back
    assert eventually(lambda: r.getStandardAnalogInput0() or None, what="analog loopback") == pytest.approx(3.0)

    async def set_through_modbus(client):
        await client.write_register(2, 1 << 1)
        # the box reads its inputs into its I/O image at the next control cycle: poll until then
        deadline = time.monotonic() + 10
        while not (value := (await regs(client, 0))[0]) & (1 << 1) and time.monotonic() < deadline:
            pass
        return value
    assert modbus(box.host, set_through_modbus) == (1 << 5) | (1 << 1)


def test_a_factory_that_returns_no_model_is_refused():
    box = EmulatorProcess(free_host(), modbus_port=MODBUS_PORT, model="tests.support.controlbox_models:not_a_model")
    with pytest.raises(LinkLostError):
        box.start(timeout_s=30)
    assert box.proc.returncode == 2 and "not a ControlBoxModel" in box.log()
    box.__exit__(None, None, None)


def test_a_killed_box_aborts_the_io_client_and_disconnects_receive(start_box):
    """ur_rtde's IO interface aborts its process from the destructor when its peer died;
    that is why every client here runs in a child process."""
    box = start_box()
    io = UrClient("io", box.host)
    r = UrClient("receive", box.host)
    try:
        assert io.isConnected() and r.isConnected()
        box.kill()
        eventually(lambda: not r.isConnected(), what="receive notices")
        assert io.wait_exit(timeout_s=20) == -signal.SIGABRT
        assert "End of file" in io.stderr()
        assert r.wait_exit(timeout_s=20) == 0
    finally:
        io.kill()
        r.kill()


def test_model_time_runs_with_the_wall_clock_only_as_a_lower_bound(start_box):
    """The box's clock is monotonic and never runs ahead of the process's time."""
    box = start_box()
    t0 = box.state()["t"]
    wall0 = time.monotonic()
    t1 = box.wait_for(lambda s: s["t"] > t0, what="model time advancing")["t"]
    assert 0 < t1 - t0 <= time.monotonic() - wall0 + 0.05
    assert math.isfinite(t1)

