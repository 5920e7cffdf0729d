"""Contract every backend honours, then what only the simulated cell promises.

The contract runs over every backend: the simulated cell in-process, the ur-rtde
and Modbus drivers against ``fluidsense simcell`` (an emulated UR control box in its
own process, backed by the simulated plant), and the serial driver against
``python -m lab simserial`` (the firmware's host board on a pty, fed by the simulated plant).

(Its in-process tests: tests/unit/test_backends.py.)
"""

from __future__ import annotations

import asyncio
import contextlib

import numpy as np
import pytest
from fluidsense.common.errors import CommandError, DriverError, SafetyError
from fluidsense.controller.config import load_cell_config
from fluidsense.drivers.registry import build_backend
from support.harness import free_simcell, sim_config

BACKENDS = ["sim", "ur", "modbus", "serial"]


@pytest.fixture
def make_backend(tmp_path):
    with contextlib.ExitStack() as boxes:
        def make(kind: str):
            if kind == "sim":
                cell = sim_config(tmp_path)
            elif kind == "serial":
                from support.serial import SimSerialProcess, serial_config

                cell = serial_config(tmp_path)
                boxes.callback(SimSerialProcess(cell).stop)
            else:
                _, cell = boxes.enter_context(free_simcell(tmp_path, kind))
            cfg = load_cell_config(cell)
            return build_backend(cfg.driver, cfg.profile.hardware)

        yield make


@pytest.mark.parametrize("kind", BACKENDS)
def test_backend_contract(kind, make_backend):
    async def body():
        backend = make_backend(kind)
        with pytest.raises(DriverError, match="not set up"):
            await backend.source.read_block()
        async with backend:
            blocks = [await backend.source.read_block() for _ in range(5)]
            # timestamped blocks: strictly increasing, no gaps unless reported as missed
            t = np.concatenate([b.t for b in blocks])
            assert np.all(np.diff(t) > 0)
            dt = 1.0 / backend.source.rate_hz
            gaps = np.round(np.diff(t) / dt).astype(int) - 1
            # every slot without a sample is reported missed (a stall, a read with nothing
            # new): the gaps between samples and the slots before the first one, plus any
            # slots of the last block after its last sample (fewer than a block)
            unreported = sum(b.missed for b in blocks) - (gaps.sum() + int(np.round(t[0] / dt)))
            assert 0 <= unreported < max(len(b) for b in blocks) + 1
            assert [b.seq for b in blocks] == sorted({b.seq for b in blocks})
            for b in blocks:
                assert b.values.shape == (len(b.t), len(b.channels))
                assert "p_act" in b.channels
            # valves: names checked, state tracked, safe state closes all
            with pytest.raises(CommandError, match="unknown valve"):
                await backend.valves.set("nope", True, t[-1])
            await backend.valves.set("supply", True, t[-1])
            assert backend.valves.is_open("supply")
            await backend.valves.safe(t[-1])
            assert not any(backend.valves.state.values())
            # regulator: a setpoint outside the limits never reaches the device
            backend.regulator.set_limits(-5e3, 90e3)
            with pytest.raises(SafetyError, match="outside"):
                await backend.regulator.set_setpoint(120e3, t[-1])
            with pytest.raises(SafetyError):
                await backend.regulator.set_setpoint(float("nan"), t[-1])
            await backend.regulator.set_setpoint(63e3, t[-1])
            assert backend.regulator.setpoint_pa == 63e3
            # arm: a pose of six finite numbers; what it must not do is refused before the device
            if backend.arm is not None:  # the serial device drives no arm
                pose = backend.arm.tcp_pose
                assert len(pose) == 6 and np.all(np.isfinite(pose))
                with pytest.raises(SafetyError, match="outside"):
                    await backend.arm.move_l(pose, 2 * backend.arm.max_speed, 1.0, t[-1])
                with pytest.raises(CommandError, match="6 finite numbers"):
                    await backend.arm.move_l([*pose[:5], float("nan")], 0.1, 1.0, t[-1])
                assert backend.arm.tcp_pose == pytest.approx(pose, abs=1e-6)
        assert not backend.source.connected

    asyncio.run(body())


def test_cycle_to_cycle_variation_is_the_papers(virtual_controller):
    """Paper cycling test: empty grip 34.5951 +- 0.0824 kPa (95 %) over 111 cycles, i.e. a
    cycle-to-cycle sd near 0.04 kPa, with per-sample noise sd about 0.07 kPa."""

    async def body(ctrl):
        return [await ctrl.run_cycle() for _ in range(25)]

    results = virtual_controller(body)
    p_eq = np.array([r.p_eq for r in results]) / 1e3
    sd_within = np.mean([r.p_sd for r in results]) / 1e3
    assert 0.025 < np.std(p_eq, ddof=1) < 0.06
    assert sd_within == pytest.approx(0.07, rel=0.1)
    assert np.mean(p_eq) == pytest.approx(34.6, abs=0.15)
