"""The serial driver over a real pty against the firmware, fed by the simulated cell: frames
round-trip, damaged bytes cost only their frames, a reset device and a silent link latch
their faults, the firmware vents by itself when the daemon dies, and a sorting-style cycle
reads sensible pressures. Two boards: the host board (the C protocol code compiled for
Linux) for everything, and the AVR image itself run by simavr (an ATmega328P at 16 MHz,
``--board avr``) for what only a device can show: round trip, venting, a sorting task, and
a reset by its hardware watchdog. The driver-side behaviours (damaged frames, a silent
link, a device that does not fit) are the same whatever the board and run on the host one.

Timing is never asserted on the wall clock: slots are counted from the device's ticks,
the vent is measured in device ticks (and, on the AVR, in its cycles), and waits are for
events (frames, messages, the board's own report), each with a generous bound against hangs."""

from __future__ import annotations

import asyncio
import os
import select
import signal
import termios
import tty

import numpy as np
import pytest
from fluidsense.common.errors import DriverError, LinkLostError
from fluidsense.controller.config import load_cell_config
from fluidsense.drivers.registry import build_backend
from fluidsense.drivers.serial import protocol as p
from support.harness import Daemon, free_tcp_port, profile_controller
from support.serial import (
    BOARD_NAMES,
    BOARDS,
    Proxy,
    SimSerialProcess,
    needs_avr,
    serial_config,
)

pytestmark = pytest.mark.timeout(300)


@pytest.fixture
def simserial():
    made: list[SimSerialProcess] = []

    def start(config, *extra: str) -> SimSerialProcess:
        sim = SimSerialProcess(config, *extra)
        made.append(sim)
        return sim

    yield start
    for sim in made:
        code, _ = sim.stop()
        assert code == 0, sim.final_stderr
        assert "Traceback" not in sim.final_stderr, sim.final_stderr


async def _read(backend, n: int) -> list:
    """n blocks, kicking the device's watchdog as the controller's loop does."""
    blocks = []
    for i in range(n):
        blocks.append(await backend.source.read_block())
        if i % 10 == 0:
            await backend.watchdog.kick()
    return blocks


def _slots(blocks) -> np.ndarray:
    return np.round(np.concatenate([b.t for b in blocks]) * 1000).astype(int)


@pytest.mark.parametrize(("reader", "board"), [("thread", "host"), ("loop", "host"),
                                               pytest.param("thread", "avr", marks=needs_avr)])
def test_frames_round_trip(tmp_path, simserial, reader, board):
    config = serial_config(tmp_path, driver={"reader": reader})
    sim = simserial(config, "--board", board)
    cell = load_cell_config(config)

    async def main():
        backend = build_backend(cell.driver, cell.profile.hardware)
        await backend.setup()
        try:
            # the connection began with the safe outputs, read back from the device's frames
            assert backend.valves.reported == {"supply": False, "actuate": False}
            assert sim.control(cmd="state")["outputs"] == 0b01  # supply energised (normally open), actuate off
            blocks = await _read(backend, 30)
            slots = _slots(blocks)
            assert np.array_equal(np.diff(slots), np.ones(len(slots) - 1))  # every tick, once, in order
            t = np.concatenate([b.t for b in blocks])
            late = t - slots / 1000.0  # each sample stamped from its tick plus the conversion's reported delay
            if board == "host":
                assert np.array_equal(late, np.zeros(len(t)))  # the host board evaluates its inputs at the tick
            else:  # the AVR: the timer interrupt's latency (TCNT2 read in the ISR), under 7 us (below)
                assert np.all((late > 0) & (late < 8e-6)), late
            assert sum(b.missed for b in blocks[1:]) == 0 and blocks[0].missed == slots[0]  # only before the first
            assert all(b.channels == ("p_act", "p_tank") and b.values.shape == (10, 2) for b in blocks)

            await backend.regulator.set_setpoint(50e3, 0.0)
            await backend.valves.set("supply", True, 0.0)
            assert await backend.valves.read_back() == {"supply": True, "actuate": False}
            state = sim.control(cmd="state")
            assert state["valves"] == {"supply": True, "actuate": False}  # the plant's valve followed the pin
            blocks = await _read(backend, 100)  # one second: the 0.4 l tank charges (time constant ~0.1 s)
            truth = sim.control(cmd="state")["pressures_kpa"]
            p_tank = blocks[-1].channel("p_tank") / 1e3
            assert abs(p_tank.mean() - 50.0) < 1.0  # the regulator's command came through (its own error ~0.1)
            assert abs(p_tank.mean() - truth["p_tank"]) < 0.5  # 10-bit counts of a settled tank: the plant's truth
            stats = backend.source.link_stats()
            assert stats["lost_frames"] == 0 and stats["corrupt_frames"] == 0
            # every command sent, each retry included, was acknowledged: none was lost on the way. (A
            # retry itself is the protocol working, not a fault: simavr starved of CPU, or this
            # process, answers later than ack_timeout_s; the device acknowledges a repeat again.)
            assert stats["acks"] == stats["commands"] + stats["retries"], stats
            assert stats["device"]["board"] == BOARD_NAMES[board] and stats["device"]["adc_bits"] == 10
        finally:
            await backend.stop()
        state = sim.control(cmd="state")  # STOP at the end left the device safe and quiet
        assert state["outputs"] == 0b01 and not state["streaming"] and not state["armed"]

    asyncio.run(main())


class _Port:
    """The device's pty, spoken to frame by frame with the protocol module (no driver)."""

    def __init__(self, path: str):
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd, termios.TCSANOW)  # TCSAFLUSH, the default, would drop what the device sent
        self.splitter = p.Splitter()
        self.pending: list[bytes] = []
        self.samples: list[p.Sample] = []  # every sample frame read, kept in order
        self.seq = 0
        # The device announces itself once its USART is up; a command written before that
        # (the simulated MCU may not have run its set-up when its pty appears) is lost, as
        # on a real board: this host has no retries, so it waits for the announcement.
        info = self.next()
        assert isinstance(info, p.Info) and (info.session, info.reset_cause) == (0, "power-on"), info

    def command(self, kind: int, args: bytes = b"") -> p.Ack:
        """One command and its ACK (frames before the ACK are dropped)."""
        self.seq += 1
        os.write(self.fd, p.command(kind, self.seq, args))
        while not (isinstance(f := self.next(), p.Ack) and f.command_seq == self.seq):
            pass
        return f

    def next(self):
        while not self.pending:
            assert select.select([self.fd], [], [], 30)[0], "the device went quiet"
            self.pending += self.splitter.feed(os.read(self.fd, 4096))
        f = p.parse(self.pending.pop(0))
        if isinstance(f, p.Sample):
            self.samples.append(f)
        return f


@needs_avr
def test_the_timer_interrupt_waits_at_most_one_short_handler(tmp_path, simserial):
    """The AVR stamps each sample with the timer interrupt's latency (TCNT2 read in the
    handler, 0.5 us a count): its bound is the longest span with interrupts off. The USART
    receive handler is that span, 72 cycles, then one instruction and the timer handler's
    own 35 cycles up to its TCNT2 read (avr-objdump of build/avr/fluidsense.elf): 111 cycles,
    6.9 us at 16 MHz, so every sample reports under 8 us. The image once copied each whole
    frame into its send ring with interrupts off (an ACK: about 20 bytes, 12 us): a command
    acknowledged across a sample's tick made that sample 10 us late in a make test run. 600
    heartbeats, each sent as the last one's ACK arrives, land on every phase of the tick."""
    sim = simserial(serial_config(tmp_path), "--board", "avr")
    port = _Port(sim.port)
    try:
        assert port.command(p.START, p.start_args(1, 1000, 500, 0, 0x03, 0x03, (0, 0))).status == p.OK
        for _ in range(600):
            assert port.command(p.HEARTBEAT).status == p.OK
        assert port.command(p.STOP).status == p.OK
    finally:
        os.close(port.fd)
    late_us = np.array([s.late_us for s in port.samples if s.session == 1])
    assert len(late_us) > 200, len(late_us)  # the heartbeats spanned many ticks
    assert late_us.min() >= 1 and late_us.max() < 8, np.bincount(late_us)


@pytest.mark.parametrize("board", BOARDS)
def test_every_session_starts_at_tick_0(tmp_path, simserial, board):
    """40 sessions in a row, each STARTed wherever the device's sampling happens to be:
    the first sample of each is tick 0, of that session, without an ADC overrun. (The AVR
    image once sent the sample its ADC was converting when START came, ticked by the old
    count: a tick going backwards, which the driver takes for a reset.) Each STOP's ACK
    leaves the board quiet, as the board itself reports it when asked right after the ACK
    (the simulated AVR once told its plant only at its next tick: a test that asked
    between the two read `streaming` after STOP.)"""
    sim = simserial(serial_config(tmp_path), "--board", board)
    port = _Port(sim.port)
    try:
        for session in range(1, 41):
            ack = port.command(p.START, p.start_args(session, 1000, 500, 0, 0x03, 0x03, (0, 0)))
            assert ack.status == p.OK and ack.session == session
            first = port.next()
            while not isinstance(first, p.Sample):
                first = port.next()
            assert (first.session, first.tick, first.flags & p.F_ADC_LATE) == (session, 0, 0), first
            assert port.command(p.STOP).status == p.OK
            state = sim.control(cmd="state")
            assert (state["streaming"], state["armed"], state["session"]) == (False, False, 0), state
    finally:
        os.close(port.fd)


def _proxied(tmp_path, simserial, **driver):
    """The board on device.tty, the driver on link.tty through the damaging proxy."""
    sim = simserial(serial_config(tmp_path, port=tmp_path / "device.tty"))
    config = serial_config(tmp_path, port=tmp_path / "link.tty", driver=driver)
    return sim, Proxy(sim.port, tmp_path / "link.tty"), load_cell_config(config)


def test_corrupt_and_dropped_bytes_cost_only_their_frames(tmp_path, simserial):
    sim, proxy, cell = _proxied(tmp_path, simserial)

    async def main():
        backend = build_backend(cell.driver, cell.profile.hardware)
        await backend.setup()
        try:
            blocks = await _read(backend, 20)
            proxy.damage(corrupt=5, drop=5)
            while proxy.pending():
                blocks += await _read(backend, 1)
            blocks += await _read(backend, 20)
            assert sorted(proxy.damaged) == ["corrupt"] * 5 + ["drop"] * 5
            stats = backend.source.link_stats()
            assert stats["corrupt_frames"] == 10 and stats["lost_frames"] == 10  # each seen, each counted once
            slots = _slots(blocks)
            assert len(np.unique(slots)) == len(slots)  # nothing twice
            assert slots[-1] - slots[0] + 1 - len(slots) == 10  # exactly the ten damaged frames' samples are gone
            assert sum(b.missed for b in blocks[1:]) == 10  # and reported as missed, not filled in
        finally:
            await backend.stop()

    try:
        asyncio.run(main())
    finally:
        proxy.close()


def test_damage_beyond_the_bound_is_a_driver_error_and_the_stream_goes_on(tmp_path, simserial):
    sim, proxy, cell = _proxied(tmp_path, simserial, damaged_limit=20)

    async def main():
        backend = build_backend(cell.driver, cell.profile.hardware)
        await backend.setup()
        try:
            await _read(backend, 5)
            proxy.damage(corrupt=40)
            with pytest.raises(DriverError) as err:
                await _read(backend, 200)
            assert not isinstance(err.value, LinkLostError) and "frames lost or corrupt" in str(err.value)
            blocks = await _read(backend, 10)  # the same connection carries on
            assert backend.source.link_stats()["connections"] == 1 and len(blocks) == 10
        finally:
            await backend.stop()

    try:
        asyncio.run(main())
    finally:
        proxy.close()


def _wait_vented_log(d: Daemon) -> None:
    """After a fault: the daemon reports the device's read-back safe positions (the
    reconnection confirmed them), so that a reset is accepted."""
    while True:
        _, msg = d.next_message("log", timeout_s=60)
        if msg.get("vented") is True:
            return


def test_a_device_reset_latches_a_driver_fault_and_the_daemon_reconnects(tmp_path, simserial):
    config = serial_config(tmp_path)
    sim = simserial(config)
    d = Daemon(config)
    try:
        d.wait_welcome()
        sim.control(cmd="reset")  # as a brown-out: the board restarts with outputs low, ticks from 0
        _, fault = d.next_message("fault")
        assert fault["kind"] == "driver" and "reset" in fault["detail"]
        _wait_vented_log(d)
        assert d.request({"cmd": "reset"})["ok"]
        status = d.request({"cmd": "status"})
        link = status["source_link"]
        assert status["fault"] is None and link["resets"] == 1 and link["connections"] == 2
        assert status["valves"] == {"supply": False, "actuate": False}
    finally:
        assert d.close() == 0


def test_a_silent_link_latches_link_lost_and_the_daemon_reconnects(tmp_path, simserial):
    sim = simserial(serial_config(tmp_path, port=tmp_path / "device.tty"))
    proxy = Proxy(sim.port, tmp_path / "link.tty")
    d = Daemon(serial_config(tmp_path, port=tmp_path / "link.tty"))
    try:
        d.wait_welcome()
        proxy.hold(True)  # the cable goes quiet; the port stays open
        _, fault = d.next_message("fault")
        assert fault["kind"] == "link_lost" and "no valid frame" in fault["detail"]
        assert fault["vented"] == "unknown"
        proxy.hold(False)
        _wait_vented_log(d)
        assert d.request({"cmd": "reset"})["ok"]
        assert d.request({"cmd": "status"})["source_link"]["connections"] == 2
    finally:
        assert d.close() == 0
        proxy.close()


def _inflate(d: Daemon, sim: SimSerialProcess) -> None:
    """A cycle started, up to its inflation: the actuate valve open on the device's pin."""
    d.wait_welcome()
    assert d.request({"cmd": "cycle"})["ok"]
    d.wait_state("actuate", 30)
    assert sim.control(cmd="state")["valves"]["actuate"] is True


@pytest.mark.parametrize("board", BOARDS)
def test_the_firmware_vents_when_the_daemon_dies(tmp_path, simserial, board):
    config = serial_config(tmp_path)
    sim = simserial(config, "--board", board)
    d = Daemon(config, new_session=True)
    try:
        _inflate(d, sim)
        os.killpg(d.proc.pid, signal.SIGKILL)  # the daemon and its helpers: no STOP, no heartbeat
        d.proc.wait(30)
        # the board says when its watchdog fires (stderr): wait for that event
        said = b""
        fd = sim.proc.stderr.fileno()  # unbuffered: select must see every byte not yet read
        while b"vented at tick" not in said:
            assert select.select([fd], [], [], 30)[0], f"the board never vented: {said!r}"
            said += os.read(fd, 65536)
        state = sim.control(cmd="state")
        (vent,) = state["vents"]
        # 0.5 s at 1 kHz: the watchdog fires on the first tick more than 500 ticks after the last heartbeat
        assert vent["tick"] - vent["last_heartbeat_tick"] == 501
        if board == "avr":  # in the MCU's cycles: the heartbeat frame's last byte to the valve pins
            assert 0.500 < vent["since_heartbeat_s"] < 0.5013, vent
        assert state["outputs"] == 0b01 and state["valves"] == {"supply": False, "actuate": False}
        assert state["vented"] and state["streaming"]
        for _ in range(400):  # the actuator empties through the 3/2 valve's vent port
            if sim.control(cmd="state")["pressures_kpa"]["p_act"] < 1.0:
                break
            select.select([], [], [], 0.05)  # poll interval of a wait bounded at 20 s; nothing is timed
        else:
            raise AssertionError(f"the actuator did not vent: {sim.control(cmd='state')}")
    finally:
        d.close()


@needs_avr
def test_a_stalled_main_loop_is_reset_by_the_hardware_watchdog(tmp_path, simserial):
    """The AVR image's main loop stops while the gripper inflates (its interrupts go on):
    the MCU's own watchdog resets it, it comes up with every output low (the valves'
    power-on state: the actuator vents), says why (reset cause watchdog), and the daemon
    latches a driver fault, reconnects and confirms the safe positions."""
    config = serial_config(tmp_path)
    sim = simserial(config, "--board", "avr")
    d = Daemon(config)
    try:
        _inflate(d, sim)
        sim.control(cmd="stall")
        _, fault = d.next_message("fault")
        assert fault["kind"] == "driver" and "the device reset (watchdog)" in fault["detail"], fault
        state = sim.control(cmd="state")
        assert state["reset_causes"] == ["watchdog"] and state["vents"] == []  # its watchdog, not the heartbeat's
        assert state["valves"]["actuate"] is False
        _wait_vented_log(d)
        assert d.request({"cmd": "reset"})["ok"]
        status = d.request({"cmd": "status"})
        link = status["source_link"]
        assert link["resets"] == 1 and link["connections"] == 2 and link["device"]["reset_cause"] == "watchdog"
        assert status["fault"] is None and status["valves"] == {"supply": False, "actuate": False}
    finally:
        assert d.close() == 0


# the AVR image's run of the same, half a minute in simavr: tests/accept/test_serial_avr.py
@pytest.mark.parametrize("board", ["host"])
def test_sorting_cycles_through_the_serial_driver_read_sensible_pressures(tmp_path, simserial, board):
    """Free air, then 40 and 100 mm cylinders, through daemon -> pty -> firmware -> plant:
    each P_eq within 0.4 kPa of the same cycle on the in-process simulated cell (10-bit
    ADC: 0.084 kPa per count for p_act, plus the regulator's cycle-to-cycle spread), bigger
    objects higher, and not one sample missed."""
    config = serial_config(tmp_path, control_port=free_tcp_port())
    simserial(config, "--board", board)
    d = Daemon(config)
    scenes = [{"kind": "none"}, {"kind": "cylinder", "diameter_mm": 40}, {"kind": "cylinder", "diameter_mm": 100}]
    got = []
    try:
        d.wait_welcome()
        d.next_message("heartbeat")  # the first block is in: the slots before it (the safe-state check) are behind us
        for scene in scenes:
            assert d.request({"cmd": "scene", "scene": scene})["ok"]
            assert d.request({"cmd": "cycle"})["ok"]
            _, result = d.next_message("cycle", timeout_s=60)
            assert result["ok"] and result["missed"] == 0, (result, d.request({"cmd": "status"})["fault"])
            got.append(result["p_eq_kpa"])
        assert d.request({"cmd": "status"})["source_link"]["lost_frames"] == 0
    finally:
        assert d.close() == 0

    async def body(ctrl):
        from fluidsense.common.scenes import Scene
        from pydantic import TypeAdapter

        out = []
        for scene in scenes:
            await ctrl.scene.place(TypeAdapter(Scene).validate_python(scene))
            out.append((await ctrl.run_cycle()).p_eq / 1e3)
        return out

    expected = profile_controller("sorting-gripper-quick", body)
    assert got[0] < got[1] < got[2]
    assert np.allclose(got, expected, atol=0.4), (got, expected)


def test_a_device_that_does_not_fit_the_config_stops_the_daemon_with_exit_2(tmp_path, simserial):
    """The device says what it is at every connection (INFO): a config that expects a 12-bit
    ADC on a 10-bit device is a bad setting, not a link to retry for ever."""
    sim = simserial(serial_config(tmp_path))
    d = Daemon(serial_config(tmp_path, port=sim.port, driver={"adc": {"bits": 12, "reference_v": 5.0}}))
    try:
        assert d.proc.wait(60) == 2
        err = d.proc.stderr.read().decode()
        assert "does not fit this config" in err and "ADC has 10 bits" in err
        assert "Traceback" not in err
    finally:
        d.close()
