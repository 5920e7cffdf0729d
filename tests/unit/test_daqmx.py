"""The NI-DAQmx driver (``driver: {kind: nidaqmx}``).

Mocked: only ``nidaqmx.Task`` and ``nidaqmx.system.WatchdogTask``
(tests/support/daqmx_fake.py), because NI's driver library cannot be installed here. The config validation, the channel and scale mapping, the read loop,
the error translation and the output tasks are the driver's real code, calling a
stand-in whose every method is bound against the real nidaqmx signatures. A test against
a real device is marked ``hardware``.
"""

from __future__ import annotations

import asyncio
import os
from pathlib import Path

import numpy as np
import pytest
from fluidsense.common.errors import (
    ConfigError,
    DeviceTimeoutError,
    DriverError,
    LinkLostError,
    SafetyError,
)
from fluidsense.controller.config import load_cell_config
from fluidsense.drivers.daqmx.backend import BufferOverflowError, build
from nidaqmx.constants import (
    AcquisitionType,
    Level,
    LineGrouping,
    OverwriteMode,
    TerminalConfiguration,
    WatchdogAOExpirState,
)
from nidaqmx.error_codes import DAQmxErrors
from nidaqmx.errors import DaqNotFoundError
from support.configs import cell_config, whole
from support.daqmx_fake import FakeRig, daq_error
from support.cli import run_cli
from support.harness import CONFIG, REPO

EXAMPLE = CONFIG / "cell-nidaqmx.yaml"


def _config(tmp_path: Path, check: bool = True, **driver) -> Path:
    return cell_config(tmp_path, EXAMPLE, check=check, driver=driver)


def _backend(tmp_path: Path, **driver):
    cfg = load_cell_config(_config(tmp_path, **driver))
    rig = FakeRig()
    return build(cfg.driver, cfg.profile.hardware, task_factory=rig, watchdog_factory=rig.watchdog), rig, cfg


def _signals(cfg, pressures_pa: np.ndarray) -> list[tuple[float, ...]]:
    """What the sensors put on the inputs for these pressures (rows: samples, columns: the
    profile's channels)."""
    sensors = [cfg.driver.wiring.sensors[c] for c in cfg.profile.hardware.channels]
    return [tuple(s.transfer.to_signal(p) for s, p in zip(sensors, row)) for row in pressures_pa]


# ------------------------------------------------------------------ config
@pytest.mark.parametrize("driver, field, reason", [
    ({"wiring": whole({"valves": {"supply": {"line": 0}, "actuate": {"line": 0}},
                       "sensors": {"p_act": {"ai": 0, "transfer": {"kind": "linear", "range_kpa": [0, 100]}},
                                   "p_tank": {"ai": 1, "transfer": {"kind": "linear", "range_kpa": [0, 900]}}},
                       "regulator": {"analog_output": 0}})}, "driver.wiring", "two valves on one digital line"),
    ({"buffer_s": 0.1, "rate_hz": 100, "block_size": 5}, "driver", "at least four blocks"),
    ({"device": "Dev1; rm"}, "driver.device", "pattern"),
    ({"wiring": whole({"valves": {"supply": {"line": 0}, "actuate": {"line": 1}},
                       "sensors": {"p_act": {"ai": 0, "transfer": {"kind": "linear", "range_kpa": [0, 100]}}},
                       "regulator": {"analog_output": 0}})}, "driver.wiring", "channels ['p_tank'] have no analog input"),
])
def test_a_config_the_driver_cannot_use_is_refused_at_load(tmp_path, driver, field, reason):
    path = _config(tmp_path, check=False, **driver)
    with pytest.raises(ConfigError) as err:
        load_cell_config(path)
    text = str(err.value)
    assert text.startswith(f"{path}: {field}"), text
    assert reason in text and "\n" not in text


def test_the_cli_refuses_a_bad_nidaqmx_config_with_one_line_and_exit_2(tmp_path, capsys):
    path = _config(tmp_path, check=False, rate_hz=0)
    out = run_cli(capsys, "run", "--config", path, cwd=REPO)
    assert out.returncode == 2, out.stderr
    assert f"{path}: driver.rate_hz:" in out.stderr and "Traceback" not in out.stderr


# ------------------------------------------------------------------ set-up
def test_channels_scales_and_timing_reach_the_tasks_as_configured(tmp_path):
    backend, rig, cfg = _backend(tmp_path)

    async def body():
        async with backend:
            return rig.task("ai"), rig.task("do"), rig.task("ao")

    ai, do, ao = asyncio.run(body())
    chans = ai.channels("ai_voltage")
    assert [c["physical_channel"] for c in chans] == ["Dev1/ai0", "Dev1/ai1"]
    assert [c["name_to_assign_to_channel"] for c in chans] == ["p_act", "p_tank"]
    assert all(c["terminal_config"] is TerminalConfiguration.RSE for c in chans)
    assert [(c["min_val"], c["max_val"]) for c in chans] == [(0.0, 5.0), (0.0, 5.1)]  # 0 to each sensor's supply
    (_, timing), = [c for c in ai.calls if c[0] == "cfg_samp_clk_timing"]
    assert timing["rate"] == 1000 and timing["sample_mode"] is AcquisitionType.CONTINUOUS
    assert timing["samps_per_chan"] == 2000 and timing["source"] == ""
    assert ai.in_stream.set == {"input_buf_size": 2000,
                                "over_write": OverwriteMode.DO_NOT_OVERWRITE_UNREAD_SAMPLES}
    assert [(c["lines"], c["name_to_assign_to_lines"], c["line_grouping"]) for c in do.channels("do")] == [
        ("Dev1/port0/line0", "supply", LineGrouping.CHAN_PER_LINE),
        ("Dev1/port0/line1", "actuate", LineGrouping.CHAN_PER_LINE)]
    # the safe positions first: the tank isolated (the normally-open supply valve energised),
    # the actuator vented (the 3/2 valve de-energised); the regulator at 0 kPa
    assert do.written[0] == [True, False]
    (ao_chan,) = ao.channels("ao_voltage")
    assert ao_chan["physical_channel"] == "Dev1/ao0" and (ao_chan["min_val"], ao_chan["max_val"]) == (0.0, 10.0)
    assert ao.written == [0.0]
    assert all(t.closed for t in rig.tasks)  # stopped with the backend


def test_a_current_loop_sensor_gets_a_current_channel_in_amps(tmp_path):
    p_tank = whole({"ai": 3, "terminal": "differential",
                    "transfer": {"kind": "linear", "output": "current", "range_kpa": [0, 1000]}})
    backend, rig, _ = _backend(tmp_path, wiring={"sensors": {"p_tank": p_tank}})

    async def body():
        async with backend:
            return rig.task("ai")

    (chan,) = asyncio.run(body()).channels("ai_current")
    assert chan["physical_channel"] == "Dev1/ai3" and chan["terminal_config"] is TerminalConfiguration.DIFF
    assert (chan["min_val"], chan["max_val"]) == pytest.approx((0.004, 0.020))


# ------------------------------------------------------------------ the read loop
def test_blocks_carry_device_clock_time_and_pressures_through_each_transfer(tmp_path):
    backend, rig, cfg = _backend(tmp_path)
    rng = np.random.default_rng(3)
    truth = np.column_stack([rng.uniform(-30e3, 30e3, 35), rng.uniform(0, 800e3, 35)])

    async def body():
        async with backend:
            rig.task("ai").acquire(_signals(cfg, truth))
            blocks = [await backend.source.read_block() for _ in range(3)]
            with pytest.raises(DeviceTimeoutError):  # 5 samples left: a block is not complete
                await backend.source.read_block()
            return blocks, rig.task("ai").calls

    blocks, calls = asyncio.run(body())
    t = np.concatenate([b.t for b in blocks])
    np.testing.assert_allclose(t, np.arange(30) / 1000.0)
    np.testing.assert_allclose(np.vstack([b.values for b in blocks]), truth[:30], rtol=1e-9, atol=1e-6)
    assert [b.seq for b in blocks] == [1, 2, 3] and all(b.missed == 0 for b in blocks)
    assert blocks[0].channels == ("p_act", "p_tank")


def test_a_full_buffer_is_a_driver_fault_and_the_next_block_reports_the_slots_lost(tmp_path):
    backend, rig, cfg = _backend(tmp_path, buffer_s=0.1)  # 100 samples
    row = _signals(cfg, np.array([[1e3, 2e3]]))[0]

    async def body():
        async with backend:
            first = rig.task("ai")
            first.acquire([row] * 10)
            before = await backend.source.read_block()
            first.acquire([row] * 101)  # one more than the buffer holds, unread
            with pytest.raises(BufferOverflowError, match="overflowed: samples were lost"):
                await backend.source.read_block()
            # the next read starts a new acquisition; the first read finds nothing yet
            with pytest.raises(DeviceTimeoutError):
                await backend.source.read_block()
            second = rig.task("ai")
            second.acquire([row] * 10)
            after = await backend.source.read_block()
            assert second is not first and first.closed and second.started and not second.closed
            return before, after

    before, after = asyncio.run(body())
    assert backend.source.overflows == 1
    # sample time goes on: the new acquisition's first sample sits after every slot reported missed
    k_first = round(after.t[0] * 1000)
    assert k_first == round(before.t[-1] * 1000) + 1 + after.missed
    assert after.missed >= 0


def test_daqmx_errors_become_the_faults_they_mean(tmp_path):
    backend, rig, _ = _backend(tmp_path)

    async def body():
        async with backend:
            rig.fail_on["read"] = daq_error(DAQmxErrors.DEVICE_REMOVED, "Device has been removed.")
            with pytest.raises(LinkLostError, match="unplugged"):
                await backend.source.read_block()
            rig.fail_on["write"] = daq_error(DAQmxErrors.DEVICE_REMOVED)
            with pytest.raises(LinkLostError):
                await backend.valves.set("actuate", True, 0.0)

    asyncio.run(body())
    backend, rig, _ = _backend(tmp_path)
    rig.fail_on["add_ai_voltage_chan"] = daq_error(DAQmxErrors.INVALID_DEVICE_ID, "Device identifier is invalid.")
    with pytest.raises(ConfigError, match="driver: nidaqmx Dev1: Device identifier is invalid"):
        asyncio.run(backend.source.setup())
    assert rig.task("ai").closed  # a task that failed to set up is not left open
    backend, rig, _ = _backend(tmp_path)
    rig.fail_on["start"] = DaqNotFoundError("Could not find an installation of NI-DAQmx.", -1)
    with pytest.raises(ConfigError, match="install the NI-DAQmx runtime"):
        asyncio.run(backend.source.setup())


# ------------------------------------------------------------------ outputs
def test_valves_and_regulator_write_levels_and_volts_and_read_back(tmp_path):
    backend, rig, _ = _backend(tmp_path)

    async def body():
        async with backend:
            do, ao = rig.task("do"), rig.task("ao")
            await backend.valves.set("actuate", True, 0.0)
            await backend.valves.set("supply", True, 0.0)
            assert do.written[-2:] == [[True, True], [False, True]]
            assert await backend.valves.read_back() == {"supply": True, "actuate": True}
            rig.line_levels = [True, True]  # a line held otherwise than written (a stuck relay)
            assert await backend.valves.disagreement() == {"supply": False}
            backend.regulator.set_limits(0.0, 500e3)
            await backend.regulator.set_setpoint(450e3, 0.0)
            with pytest.raises(SafetyError):
                await backend.regulator.set_setpoint(600e3, 0.0)
            return ao.written

    written = asyncio.run(body())
    assert written == [0.0, pytest.approx(5.0)]  # 450 of 900 kPa on 0-10 V; the refused one never written


@pytest.mark.hardware
def test_the_daqs_watchdog_holds_the_safe_levels_and_the_sample_loop_resets_it(tmp_path):
    """Armed at set-up, after the safe levels are written: on expiry the device sets the
    supply line high (a normally-open valve energised: tank isolated), the actuate line
    low (actuator vented) and ao0 to the regulator's 0 kPa; the controller's kicks reset
    its timer; an expiry is a driver fault, cleared before the next cycle."""
    backend, rig, _ = _backend(tmp_path)

    async def body():
        await backend.setup()
        try:
            (dog,) = rig.watchdogs
            assert (dog.device, dog.timeout, dog.started) == ("Dev1", 0.5, True)
            assert dog.do_states == {"Dev1/port0/line0": Level.HIGH, "Dev1/port0/line1": Level.LOW}
            assert dog.ao_states == {"Dev1/ao0": (0.0, WatchdogAOExpirState.VOLTAGE)}
            assert rig.task("do").written and rig.task("ao").written  # the safe levels were written before
            for _ in range(4):
                await backend.watchdog.kick()
            assert dog.resets == 4
            await backend.valves.set("actuate", True, 0.0)  # inflating when the loop hangs
            dog.expire()
            with pytest.raises(DriverError, match="watchdog expired"):
                await backend.watchdog.kick()
            assert await backend.valves.read_back() == {"supply": False, "actuate": False}
            await backend.watchdog.ensure_running()
            assert dog.clears == 1 and not dog.expired
            await backend.watchdog.kick()
            assert dog.resets == 5
        finally:
            await backend.stop()
        assert dog.closed and not dog.started

    asyncio.run(body())


def test_a_daq_without_a_watchdog_is_a_config_error_unless_the_config_says_so(tmp_path):
    backend, rig, _ = _backend(tmp_path)
    rig.fail_on["WatchdogTask"] = daq_error(DAQmxErrors.WATCHDOG_TIMER_NOT_SUPPORTED, "Watchdog timer not supported.")
    with pytest.raises(ConfigError, match="has no watchdog timer.*driver.watchdog.enabled: false"):
        asyncio.run(backend.setup())
    assert all(t.closed for t in rig.tasks)  # the valves and the regulator closed again
    backend, rig, _ = _backend(tmp_path, watchdog={"enabled": False})
    assert backend.watchdog is None and rig.watchdogs == []


def test_a_daq_that_guards_only_its_digital_lines_still_arms_them(tmp_path):
    """An X Series board takes digital expiration states only: the regulator keeps its
    setpoint on expiry while the valves isolate it; the lines are armed all the same."""
    backend, rig, _ = _backend(tmp_path)
    rig.fail_on["cfg_watchdog_ao_expir_states"] = daq_error(DAQmxErrors.WATCHDOG_TIMER_NOT_SUPPORTED)

    async def body():
        await backend.setup()
        try:
            (dog,) = rig.watchdogs
            assert dog.started and len(dog.do_states) == 2 and dog.ao_states == {}
            assert not backend.watchdog.guards_regulator
        finally:
            await backend.stop()

    asyncio.run(body())


def test_a_real_daq_samples_at_its_rate():
    """On a real NI DAQ: FLUIDSENSE_NIDAQMX_CONFIG names a cell config with driver kind
    nidaqmx. Samples come at the configured rate with no slot missed."""
    path = os.environ.get("FLUIDSENSE_NIDAQMX_CONFIG")
    if not path:
        pytest.skip("set FLUIDSENSE_NIDAQMX_CONFIG to a cell config with driver kind nidaqmx")
    cfg = load_cell_config(path)

    async def body():
        backend = build(cfg.driver, cfg.profile.hardware)
        async with backend:
            blocks = [await backend.source.read_block() for _ in range(100)]
            await backend.safe_state(blocks[-1].t[-1])
        return blocks

    blocks = asyncio.run(asyncio.wait_for(body(), 60))
    t = np.concatenate([b.t for b in blocks])
    assert sum(b.missed for b in blocks) == 0
    np.testing.assert_allclose(np.diff(t), 1.0 / cfg.driver.rate_hz)


# ------------------------------------------------------------------ a block that cannot be true
# (the parser's checks on blocks from the stand-in task: nidaqmx's library cannot run here)
LIES = {
    "channels": lambda data: [*data, list(data[0])],  # a third channel's list
    "flat": lambda data: [v for col in data for v in col],  # one flat list for two channels
    "samples": lambda data: [col[:-1] for col in data],  # one sample short
    "long": lambda data: [[*col, col[-1]] for col in data],  # one sample more than asked for
    "nan": lambda data: [[float("nan"), *col[1:]] if i == 1 else col for i, col in enumerate(data)],
    "inf": lambda data: [[*col[:-1], float("inf")] for col in data],
    "nested": lambda data: [[[col[0]], *col[1:]] if i == 0 else col for i, col in enumerate(data)],
    "none": lambda data: [[None, *col[1:]] if i == 0 else col for i, col in enumerate(data)],
}
FIELD = {"channels": "channels:", "flat": "channels:", "samples": "samples:", "long": "samples:", "nan": "values:",
         "inf": "values:", "nested": "values:",
         "none": "values:"}


@pytest.mark.parametrize("lie", [*LIES, "rate"])
def test_a_block_that_cannot_be_true_is_one_fault_naming_the_field_then_a_new_acquisition(tmp_path, lie):
    """A block of another shape, another channel count, a non-number or a sample clock ten
    times fast: one DeviceProtocolError naming the field, no samples from it, and the next
    read starts a new acquisition whose sane blocks flow again, their time after every slot
    reported missed. (Before, a flat list for two channels was reshaped into pressures, a
    third channel's list read as extra samples, NaN went through as a pressure.)"""
    from fluidsense.common.errors import DeviceProtocolError

    backend, rig, cfg = _backend(tmp_path)
    row = _signals(cfg, np.array([[1e3, 2e3]]))[0]
    field = FIELD.get(lie, "rate:")

    async def body():
        async with backend:
            first = rig.task("ai")
            first.acquire([row] * 10)
            before = await backend.source.read_block()
            if lie == "rate":
                # 0.5 s of samples (the config's 1 kHz) read at once, right after the start: a
                # device whose sample clock runs far faster than the task's rate
                first.acquire([row] * 500)
                with pytest.raises(DeviceProtocolError, match=field) as err:
                    for _ in range(50):
                        await backend.source.read_block()
            else:
                first.acquire([row] * 10)
                rig.lie = LIES[lie]
                with pytest.raises(DeviceProtocolError, match=field) as err:
                    await backend.source.read_block()
            with pytest.raises(DeviceTimeoutError):  # a new acquisition: nothing in it yet
                await backend.source.read_block()
            second = rig.task("ai")
            second.acquire([row] * 10)
            after = await backend.source.read_block()
            assert second is not first and first.closed and second.started and not second.closed
            return err.value, before, after

    err, before, after = asyncio.run(body())
    assert isinstance(err, DriverError) and err.field == field.rstrip(":")
    np.testing.assert_allclose(after.values, [[1e3, 2e3]] * 10, rtol=1e-9, atol=1e-6)
    assert after.missed >= 0
    if lie != "rate":  # the lying block gave no samples: the new acquisition follows every slot reported missed
        assert round(after.t[0] * 1000) == round(before.t[-1] * 1000) + 1 + after.missed
