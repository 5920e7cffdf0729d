"""The serial streamer's protocol without a device: the firmware core's own unit tests (C,
built and run here), the host side's framing against the same definitions, the clock
alignment, and the config's refusals.

(Its tests with real peers: tests/system/test_serial_protocol.py.)
"""

from __future__ import annotations

import struct

import numpy as np
import pytest
from fluidsense.common.errors import ConfigError
from fluidsense.drivers.serial import protocol as p
from fluidsense.drivers.serial.clock import Timeline
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support.harness import CONFIG
from support.serial import serial_config


def test_crc_is_ccitt_false():
    assert p.crc16(b"123456789") == 0x29B1  # the catalogue's check value for CRC-16/CCITT-FALSE


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=p.MAX_FRAME))
def test_cobs_round_trips_without_zero_bytes(data):
    enc = p.cobs_encode(data)
    assert b"\x00" not in enc and len(enc) == len(data) + 1
    assert p.cobs_decode(enc) == data


def test_a_damaged_frame_costs_itself_only():
    frames = [p.frame(struct.pack("<BBHIBBBHH2H", p.SAMPLE, 9, seq, seq, 0, p.F_ARMED, 0, 0, 0, 100, 200))
              for seq in range(5)]
    damaged = bytearray(frames[1])
    damaged[5] ^= 0x55
    cut = frames[3][:4] + frames[3][5:]
    splitter = p.Splitter()
    stream = frames[0] + bytes(damaged) + frames[2] + cut + frames[4]
    got = [p.parse(x) for i in range(0, len(stream), 7) for x in splitter.feed(stream[i:i + 7])]  # any chunking
    assert [f.seq for f in got] == [0, 2, 4] and splitter.corrupt == 2
    assert got[1].counts == (100, 200) and got[1].session == 9


def test_garbage_without_delimiters_is_dropped_and_the_stream_recovers():
    splitter = p.Splitter()
    assert splitter.feed(b"\x07" * 1000) == [] and splitter.corrupt == 1
    good = p.frame(struct.pack("<BBHBHBIBB", p.ACK, 1, 3, p.HEARTBEAT, 77, p.OK, 5, 0, 0))
    (payload,) = splitter.feed(b"\x00" + good)
    ack = p.parse(payload)
    assert isinstance(ack, p.Ack) and ack.command_seq == 77 and ack.tick == 5


def test_timeline_keeps_sample_time_on_the_device_grid_and_follows_a_drifting_clock():
    """The device's clock runs 200 ppm slow against the host's: sample times stay k / rate,
    the origin moves with the drift (measured), so origin + t stays the host time of the
    sample; a new session's ticks restart at 0 and land after the last slot."""
    tl = Timeline(1000.0)
    rng = np.random.default_rng(1)
    host0 = 100.0
    for k in range(0, 20_000):
        arrival = host0 + k / 1000.0 * (1 + 200e-6) + 0.0005 + rng.exponential(0.0003)
        assert tl.slot(k, arrival) == k
    assert tl.drift_ppm == pytest.approx(200.0, abs=5.0)
    sample_host_time = host0 + 19.999 * (1 + 200e-6) + 0.0005
    assert tl.origin + 19.999 == pytest.approx(sample_host_time, abs=50e-6)
    tl.new_session()
    k = tl.slot(0, host0 + 25.0)  # five seconds later, the device restarted its ticks
    assert k == pytest.approx(25_000 - 4, abs=3)  # 25 s of host time, less the drift
    assert tl.slot(1, host0 + 25.001) == k + 1


def test_config_refusals(tmp_path):
    from fluidsense.controller.config import load_cell_config

    def refused(driver: dict) -> str:
        with pytest.raises(ConfigError) as err:
            load_cell_config(serial_config(tmp_path, driver=driver))
        return str(err.value)

    cell = load_cell_config(CONFIG / "cell-serial-sim.yaml")
    wiring = cell.driver.wiring.model_dump()
    two = {**wiring, "sensors": {"p_act": {"adc": 0, "transfer": wiring["sensors"]["p_act"]["transfer"]},
                                 "p_tank": {"adc": 0, "transfer": wiring["sensors"]["p_tank"]["transfer"]}}}
    assert "two sensors on one analog input" in refused({"wiring": two})
    current = {**wiring, "sensors": {**wiring["sensors"], "p_tank": {"adc": 1, "transfer": {
        "kind": "linear", "output": "current", "range_kpa": [0, 500]}}}}
    assert "shunt" in refused({"wiring": current})
    assert "driver.wiring.valves.supply.output" in refused(
        {"wiring": {**wiring, "valves": {**wiring["valves"], "supply": {"output": 8}}}})
    missing = {**wiring, "valves": {"actuate": wiring["valves"]["actuate"]}}
    assert "not wired" in refused({"wiring": missing})
    assert "driver.rate_hz" in refused({"rate_hz": 1000.0})  # strict integer
    assert "driver.bogus" in refused({"bogus": 1})


# ---------------------------------------------------------------- a device that lies (valid CRC)
# lab/bench/fuzz_serial.py: each case a session started as a device would, then its frames
# through the link's own read path (a pipe for the port); `make fuzz` runs it at 1,000 cases

from lab.bench.fuzz_serial import SANE, SESSION, Run, case_strategy, driver_config, sample  # noqa: E402

DRIVER = driver_config()


def _lie(payloads: list[bytes]) -> dict:
    run = Run(DRIVER)
    run.feed(payloads)
    return run.check()


def _good(n: int, first: int = 0) -> list[bytes]:
    return [sample(SESSION, SANE + 1 + i, SANE + i, (512, 512)) for i in range(first, first + n)]


@pytest.mark.parametrize(("field", "lie"), [
    ("counts", sample(SESSION, SANE + 1, SANE, (512, 512, 512))),  # three counts, two inputs wired
    ("counts", sample(SESSION, SANE + 1, SANE, (512, 4000))),  # 4000 from a 10-bit ADC
    ("tick", sample(SESSION, SANE + 1, SANE + 10**6, (512, 512))),  # 1000 s of samples at once
    ("seq", sample(SESSION, SANE + 30_000, SANE, (512, 512))),  # 30,000 frames lost between two ticks
])
def test_one_frame_that_cannot_be_true_ends_the_session_once_naming_its_field(field, lie):
    """The frame and everything after it: one DeviceProtocolError naming the field, nothing more
    queued (the driver once queued a DriverError per frame, and the sample loop froze on them)."""
    assert _lie([lie] * 50 + _good(20, 1)) == {"blocks": 2, "ended": field, "errors": 0}


def test_a_timer_ten_times_its_rate_ends_the_session_as_rate():
    """1,000 good frames arriving at once: a timer far faster than rate_hz. Ended before a
    second of sample time passed (the slack is 0.25 s beyond the host clock)."""
    out = _lie(_good(1000))
    assert out["ended"] == "rate" and out["blocks"] <= 2 + 30, out


@settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck))
@given(payloads=case_strategy())
def test_hostile_frames_end_a_session_at_most_once_and_never_move_sample_time_ahead(payloads):
    _lie(payloads)  # Run.check asserts the properties (lab/bench/fuzz_serial.py)
