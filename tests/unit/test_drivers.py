"""The production drivers' parts that need no box: the sensor wiring's transfer functions, the
plant behind the box's outputs, and the configs the drivers refuse at load. (The drivers
against ``fluidsense simcell``, unmodified and unmocked: tests/system/test_drivers.py.)"""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
from fluidsense.common.errors import ConfigError
from fluidsense.common.wiring import Linear, Mpx, Ratiometric, RegulatorWiring
from fluidsense.controller.config import load_cell_config
from fluidsense.drivers.registry import build_backend
from fluidsense.simulator.controlbox.model import AnalogDomain
from fluidsense.simulator.controlbox.plant import PlantModel
from support.configs import DELETE, cell_config
from support.harness import CONFIG


# ------------------------------------------------------------------ wiring, in-process
def test_transfer_functions_give_datasheet_values_and_invert():
    ssc = Ratiometric(range_kpa=(-34.5, 34.5))  # Honeywell SSC: 10-90 % of 5 V
    assert ssc.to_signal(0.0) == pytest.approx(2.5)
    assert ssc.to_signal(34.5e3) == pytest.approx(4.5)
    assert ssc.to_signal(-34.5e3) == pytest.approx(0.5)
    mpx = Mpx(supply_v=5.1, a_per_kpa=0.00369, b=0.04)  # MPX4250DP: Vout = Vs (0.00369 P + 0.04)
    assert mpx.to_signal(100e3) == pytest.approx(5.1 * (0.369 + 0.04))
    loop = Linear(range_kpa=(0.0, 600.0))  # 4-20 mA transmitter
    assert loop.to_signal(300e3) == pytest.approx(12e-3)
    for transfer in (ssc, mpx, loop):
        for p in (-20e3, 0.0, 17.3e3, 63e3):
            assert transfer.to_pa(transfer.to_signal(p)) == pytest.approx(p, abs=1e-6)
    reg = RegulatorWiring(analog_output=0, range_kpa=(0.0, 900.0))  # SMC ITV1050: 0-10 V
    assert reg.to_signal(64e3) == pytest.approx(64 / 90)
    assert reg.to_pa(reg.to_signal(64e3)) == pytest.approx(64e3)
    assert reg.to_signal(2e6) == pytest.approx(10.0)  # clipped to the command range


def test_the_plant_follows_the_box_outputs_through_the_wiring():
    """Virtual time: the box's outputs drive valves and regulator as wired, and its
    analog inputs show the plant's pressures through the sensors' transfer functions."""
    cfg = load_cell_config(CONFIG / "cell-ur-sim.yaml")
    wiring = cfg.driver.wiring
    m = PlantModel(cfg.profile.hardware, wiring)
    t = 0.0

    def run(seconds):
        nonlocal t
        for _ in range(int(seconds * 500)):
            t += 0.002
            m.advance(t)

    def pressure_kpa(name):
        s = wiring.sensors[name]
        return s.transfer.to_pa(m.analog_input(s.analog_input).value) / 1e3

    m.set_analog_output(0, wiring.regulator.to_signal(64e3), AnalogDomain.VOLTAGE)
    m.on_outputs_changed(m.t)
    run(2.0)
    # the supply valve is normally open: with every output off the tank charges
    assert pressure_kpa("p_tank") == pytest.approx(64.0, abs=1.0)
    assert abs(pressure_kpa("p_act")) < 1.0
    m.set_digital_outputs(0b11, 0b01)  # isolate the tank
    m.on_outputs_changed(m.t)
    m.set_digital_outputs(0b10, 0b10)  # the 3/2 valve connects the gripper
    m.on_outputs_changed(m.t)
    run(8.0)
    p_act, p_tank = pressure_kpa("p_act"), pressure_kpa("p_tank")
    assert 30.0 < p_act < 40.0  # an empty grip settles near the paper's 34-35 kPa
    assert p_tank == pytest.approx(p_act, abs=1.0)
    m.set_digital_outputs(0b10, 0b00)  # de-energised, the 3/2 valve vents the gripper
    m.on_outputs_changed(m.t)
    run(2.0)
    assert abs(pressure_kpa("p_act")) < 1.0


def test_a_ur_config_asking_1khz_is_refused_with_the_rtde_limit(tmp_path):
    path = cell_config(tmp_path, "cell-ur-sim", check=False, driver={"rate_hz": 1000})
    with pytest.raises(ConfigError) as err:
        load_cell_config(path)
    assert str(path) in str(err.value) and "driver.rate_hz" in str(err.value)
    assert "RTDE at 500 Hz at most" in str(err.value)
    with pytest.raises(ConfigError, match="125 Hz at most on cb3"):
        load_cell_config(cell_config(tmp_path, "cell-ur-sim", check=False, driver={"rate_hz": 200, "controller": "cb3"}))


def test_wiring_that_does_not_match_the_profile_is_refused(tmp_path):
    def wiring(p_tank_input: int) -> dict:
        return {"wiring": {"valves": {"supply": DELETE}, "sensors": {"p_tank": {"analog_input": p_tank_input}}}}

    with pytest.raises(ConfigError) as err:
        load_cell_config(cell_config(tmp_path, "cell-modbus-sim", check=False, driver=wiring(0)))
    assert "two sensors on one analog input" in str(err.value)
    with pytest.raises(ConfigError, match=r"driver.wiring: valves \['supply'\] of the profile's circuit are not wired"):
        load_cell_config(cell_config(tmp_path, "cell-modbus-sim", check=False, driver=wiring(1)))


# ------------------------------------------------------------------ against fluidsense simcell
async def _blocks(source, n: int):
    return [await source.read_block() for _ in range(n)]


# ------------------------------------------------------------------ a real cell
@pytest.mark.hardware
def test_hardware_cell_samples_and_vents():
    """On a real robot cell: FLUIDSENSE_HARDWARE_CONFIG names its cell config. Samples
    arrive at the configured rate and the safe state is reached."""
    import os

    path = os.environ.get("FLUIDSENSE_HARDWARE_CONFIG")
    if not path:
        pytest.skip("set FLUIDSENSE_HARDWARE_CONFIG to the real cell's config")
    cfg = load_cell_config(path)

    async def body():
        backend = build_backend(cfg.driver, cfg.profile.hardware)
        async with backend:
            blocks = await _blocks(backend.source, 50)
            t = np.concatenate([b.t for b in blocks])
            rate = (len(t) - 1) / (t[-1] - t[0])
            assert rate == pytest.approx(backend.source.rate_hz, rel=0.02)
            await backend.safe_state(t[-1])
            assert backend.valves.in_safe_state

    asyncio.run(asyncio.wait_for(body(), 60))
