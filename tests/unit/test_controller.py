"""The controller on the simulated cell, in virtual time.

(Its tests with real peers: tests/system/test_controller.py.)
"""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
from fluidsense.common.errors import FaultError, SafetyError
from fluidsense.common.scenes import CylinderScene, EmptyScene


def true_contact_time(diameter_mm: float) -> float:
    """When the plant's true actuator pressure reaches the contact pressure, seconds after
    the valve was commanded open (valve delay included), from the plant alone."""
    from fluidsense.common.hardware import GripperActuator, TankCircuit
    from fluidsense.common.units import P_ATM
    from fluidsense.simulator.actuators import volume_law
    from fluidsense.simulator.gas import Network, Pipe, VolumeLaw
    from fluidsense.simulator.plant import Plant

    act, c = GripperActuator(), TankCircuit()
    law = volume_law(act, CylinderScene(diameter_mm=diameter_mm), P_ATM)
    net = Network(["tank", "actuator"], [VolumeLaw.constant(c.tank_m3), law],
                  [Pipe(0, 1, c.valve_resistance_pa_s_per_m3 + c.resistor_pa_s_per_m3, "v", True)])
    plant = Plant(net, {"v": True}, P_ATM, 0.05, p_initial_abs={"tank": P_ATM + 63e3})
    t = np.arange(0, 1, 1e-5)
    p = plant.pressures_abs(plant.sample(t)[0])[1] - P_ATM
    return float(t[np.argmax(p >= law.p_gauge[1])]) + c.valve_delay_s


def test_contact_time_features_against_the_plants_truth(virtual_controller):
    async def body(ctrl):
        await ctrl.scene.place(EmptyScene())
        ref = await ctrl.run_cycle(store_reference=True)
        out = {}
        for d in (40, 60, 80, 100):
            await ctrl.scene.place(CylinderScene(diameter_mm=d))
            out[d] = await ctrl.run_cycle()
        return ref, out

    ref, results = virtual_controller(body)
    assert ref.is_reference and not ref.has_reference
    for d, res in results.items():
        truth = true_contact_time(d)
        assert res.has_reference
        assert res.t_c_slope == pytest.approx(truth, abs=0.005), d
        # the threshold variant fires once dP has built up: after contact, soon after
        assert truth < res.t_c_threshold < truth + 0.06
        assert res.dp_max >= res.dp_eq > 0
    dps = [results[d].dp_eq for d in (40, 60, 80, 100)]
    assert dps == sorted(dps)  # bigger object, bigger dP


def test_cycle_result_windows_and_offset(virtual_controller):
    async def body(ctrl):
        await ctrl.scene.place(CylinderScene(diameter_mm=80))
        return await ctrl.run_cycle(label="x")

    res = virtual_controller(body)
    d = res.to_dict()
    assert d["ok"] and d["label"] == "x"
    assert d["offset_kpa"] == pytest.approx(0.3, abs=0.01)  # the sensor's offset, removed
    assert d["windows"][0]["n"] == 1000  # 1 s at 1 kHz
    assert d["t_open_s"] - d["t_start_s"] == pytest.approx(20.0, abs=0.011)
    assert d["p_eq_kpa"] == pytest.approx(37.1, abs=0.2)


def test_over_pressure_faults_vents_and_latches(virtual_controller):
    """The supply sticks open into the actuator with the regulator far above P0 (fault
    injection in the simulated cell): the cycle must fault, vent, and refuse new cycles
    until reset. A P0 within the margin of the limits, where a cycle would cross the limit
    on its own readings, is refused before anything moves (tests/unit/test_config.py checks the
    margin in profiles)."""

    async def body(ctrl):
        margin = ctrl.profile.p0_margin_kpa
        with pytest.raises(SafetyError, match=f"within {margin:.2f} kPa of the profile's limits"):
            await ctrl.run_cycle(p0_kpa=ctrl.profile.limits.max_kpa - margin / 2)
        fut = await ctrl.start_cycle()
        ctrl.backend.sim.inject("over_pressure", ctrl.now + 0.5)
        res = await fut
        status = ctrl.status()
        with pytest.raises(FaultError):
            await ctrl.run_cycle()
        ctrl.reset()
        after_reset = ctrl.status()["state"]
        with pytest.raises(SafetyError, match="outside the profile's limits"):
            await ctrl.run_cycle(p0_kpa=95.0)
        return res, status, after_reset

    res, status, after_reset = virtual_controller(body)
    assert res.aborted == "fault: over_pressure"
    assert res.t_open is None  # it never reached the actuation
    assert status["state"] == "fault"
    assert status["fault"]["kind"] == "over_pressure"
    assert status["valves"] == {"supply": False, "actuate": False} and status["vented"] is True
    assert after_reset == "idle"


@pytest.mark.parametrize("batch_s, samples", [(0.01, 10), (0.1, 100)])
def test_pressure_batches_hold_as_many_samples_as_their_length_says(tmp_path, batch_s, samples):
    """At 1 kHz in blocks of 10, a 10 ms batch is one block: n samples cover n periods."""
    from fluidsense.controller.config import load_cell_config
    from fluidsense.controller.service import Controller
    from fluidsense.drivers.registry import build_backend
    from support.harness import sim_config

    cfg = load_cell_config(sim_config(tmp_path))
    cfg = cfg.model_copy(update={"publisher": cfg.publisher.model_copy(update={"pressure_batch_s": batch_s})})

    class Capture:
        endpoint, dropped = None, 0

        def __init__(self):
            self.pressure = []

        def send(self, topic, t_s, payload):
            if topic == "pressure":
                self.pressure.append(payload)

        def close(self):
            pass

    pub = Capture()

    async def body():
        async with Controller(cfg, build_backend(cfg.driver, cfg.profile.hardware), pub) as ctrl:
            await ctrl.wait(1.0)

    asyncio.run(body())
    full = pub.pressure[:-1]  # the last may be cut short by the stop
    assert len(full) >= 1.0 / batch_s - 2
    assert {m["n"] for m in full} == {samples}
    times = np.concatenate([m["times_s"] for m in pub.pressure])
    assert np.all(np.diff(times) > 0)  # nothing sent twice, nothing out of order


def test_a_polled_sources_jitter_does_not_hold_a_batch_for_a_second_block(tmp_path):
    """A polled source stamps each read when it starts: the first sample of a block can be
    a few microseconds later than its slot while the last is on time. A 10 ms batch is
    still one block of 10 (it once waited for a second block, doubling the latency)."""
    from fluidsense.common.samples import SampleBlock
    from fluidsense.controller.config import PublisherConfig
    from fluidsense.controller.telemetry.fanout import Telemetry

    sent = []

    class Capture:
        endpoint, dropped = None, 0

        def send(self, topic, t_s, payload):
            sent.append(payload["n"])

        def close(self):
            pass

    class Clock:  # path.SampleTime
        now = 0.0

    class Source:  # path.Stream
        rate_hz, clock_origin_s = 1000.0, None

    faults = []

    class Latch:  # path.Faults
        def defer(self, detail, kind, now):
            faults.append(detail)

    clock = Clock()
    telemetry = Telemetry(Capture(), PublisherConfig(pressure_batch_s=0.01), clock=clock, stream=Source(),
                          faults=Latch())
    slots = np.arange(30) / 1000.0
    lateness = np.tile(np.r_[5e-6, np.zeros(9)], 3)  # each block's first read 5 us late
    for i in range(3):
        t = slots[10 * i:10 * i + 10] + lateness[10 * i:10 * i + 10]
        clock.now = float(t[-1])
        telemetry.on_block(SampleBlock(seq=i, t=t, values=np.zeros((10, 1)), channels=("p",)))
    assert sent == [10, 10, 10] and faults == []
