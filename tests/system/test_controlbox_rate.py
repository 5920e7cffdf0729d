"""The emulated control box refreshes what it reports at its generation's control rate, as
a real box does (500 Hz e-Series, 125 Hz CB3): its Modbus input registers and RTDE inputs
hold their value between controller cycles, so a client polling faster reads repeats.

Analog input 0 of ``tests.support.controlbox_models:ramp`` is a ramp of the box's own time, so each
value read tells when the box sampled it; counts are taken against the box's clock (the sim
control channel's ``t``, RTDE ``timestamp``), never against the wall clock.
"""

from __future__ import annotations

import math
import struct

import pytest
from pymodbus.client import ModbusTcpClient
from support.controlbox import MODBUS_PORT, RawRtde
from support.controlbox_models import RAMP_V_PER_S
from support.harness import free_simcell

GENERATIONS = [("e-series", 500.0), ("cb3", 125.0)]
WRAP_S = 10.0 / RAMP_V_PER_S  # the ramp starts again at 0 V after this long
POLLS = 1000


def ramp_cycle(volts: float, hz: float) -> float:
    """The (fractional) control cycle, modulo the ramp's wrap, at which the ramp read ``volts``."""
    return volts / RAMP_V_PER_S * hz


@pytest.mark.parametrize("controller, hz", GENERATIONS)
def test_modbus_inputs_change_at_most_once_per_control_cycle(start_box, controller, hz):
    box = start_box("--controller", controller, model="tests.support.controlbox_models:ramp")
    client = ModbusTcpClient(box.host, port=MODBUS_PORT, timeout=5, retries=0)
    assert client.connect(), "modbus connect failed"
    try:
        t_first = box.state()["t"]
        raws = []
        for _ in range(POLLS):  # back to back, as fast as the client goes (~2 kHz here)
            reply = client.read_holding_registers(4, count=1)
            assert not reply.isError(), reply
            raws.append(reply.registers[0])
        t_last = box.state()["t"]
    finally:
        client.close()
    span_s = t_last - t_first
    distinct = len(set(raws))
    # at most one new value per control cycle begun during the sampling (box time)
    cycles = math.floor(t_last * hz) - math.floor(t_first * hz) + 1
    assert distinct <= cycles, f"{distinct} values in {span_s:.3f} s of box time at {hz:g} Hz"
    assert distinct < POLLS, "a poll faster than the control rate must read repeats"
    # every value is the ramp at the start of a control cycle (raw counts are 0.15 mV apart,
    # 31 us of ramp; a value sampled between cycle starts is off the grid by up to a cycle)
    for raw in set(raws):
        k = ramp_cycle(raw / 65535 * 10.0, hz)
        assert abs(k - round(k)) / hz < 20e-6, f"raw {raw}: sampled {(k - round(k)) / hz * 1e6:.0f} us off a cycle start"
    print(f"{controller}: {POLLS} polls in {span_s * 1e3:.0f} ms of box time ({POLLS / span_s:.0f} Hz), "
          f"{distinct} distinct values ({distinct / span_s:.0f} per s)")


@pytest.mark.parametrize("controller, hz", GENERATIONS)
def test_rtde_sends_at_most_the_control_rate_with_the_inputs_of_its_cycle(start_box, controller, hz):
    box = start_box("--controller", controller, model="tests.support.controlbox_models:ramp")
    rtde = RawRtde(box.host)
    try:
        assert rtde.ask("V", struct.pack(">H", 2)) == b"\x01"
        # ask for 500 Hz on either generation: a CB3 serves its own 125 Hz
        recipe = rtde.ask("O", struct.pack(">d", 500.0) + b"timestamp,standard_analog_input0")
        assert recipe[1:] == b"DOUBLE,DOUBLE"
        assert rtde.ask("S") == b"\x01"
        packages = []
        while len(packages) < 100:
            kind, body = rtde.recv()
            if kind == "U":
                packages.append(struct.unpack(">dd", body[1:]))
    finally:
        rtde.close()
    stamps = [t for t, _ in packages]
    assert stamps == sorted(set(stamps))
    span_s = stamps[-1] - stamps[0]
    assert len(packages) - 1 <= span_s * hz + 1, f"{len(packages)} packages in {span_s:.3f} s at {hz:g} Hz"
    # each package carries the input as the box read it at the start of its own cycle
    for t, volts in packages:
        expected = math.floor(t * hz) % round(WRAP_S * hz)
        assert ramp_cycle(volts, hz) == pytest.approx(expected, abs=1e-6), f"package at {t}"


@pytest.mark.parametrize("controller, rate_hz, io_hz", [("cb3", 125, 125.0), ("io-module", 1000, 1000.0)])
def test_simcell_takes_the_generation_from_the_cell_config(tmp_path, controller, rate_hz, io_hz):
    """``fluidsense simcell`` serves the config's controller: a CB3 box refreshes at 125 Hz; an
    I/O module is served at the rate it is polled (the slowest its data sheet may promise)."""
    with free_simcell(tmp_path, "modbus", driver={"controller": controller, "rate_hz": rate_hz}) as (box, _):
        state = box.state()
    assert state["controller"] == ("e-series" if controller == "io-module" else controller)
    assert state["io_hz"] == io_hz
