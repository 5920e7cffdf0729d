"""What only the simulated cell promises, in this process: the same seed gives the same
samples, the sensor model's noise, quantisation and offset, and a command inside a
precomputed chunk acting at its time. (The contract every backend honours, over every
backend, and the cycle-to-cycle variation study: tests/system/test_backends.py.)"""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
from fluidsense.common.hardware import Hardware
from fluidsense.common.scenes import CylinderScene
from fluidsense.drivers.registry import SimDriverConfig, build_backend


# ------------------------------------------------------------- simulated only
def _sim(seed: int, scene=None):
    return build_backend(SimDriverConfig(clock="virtual", seed=seed, **({"scene": scene} if scene else {})),
                         Hardware())


async def _first_samples(backend, n_blocks: int = 50) -> np.ndarray:
    async with backend:
        blocks = [await backend.source.read_block() for _ in range(n_blocks)]
    return np.vstack([b.values for b in blocks])


def test_same_seed_same_samples_other_seed_other_noise():
    a = asyncio.run(_first_samples(_sim(7)))
    b = asyncio.run(_first_samples(_sim(7)))
    c = asyncio.run(_first_samples(_sim(8)))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_sensor_model_noise_quantisation_and_offset():
    """Vented actuator: readings = offset (0.3 kPa) + noise sd 0.07 kPa on a 0.016 kPa grid."""
    v = asyncio.run(_first_samples(_sim(3), n_blocks=2000))[:, 0]
    assert np.mean(v) == pytest.approx(300.0, abs=5.0)
    assert np.std(v) == pytest.approx(70.0, rel=0.05)
    steps = v / 16.0
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)


def test_a_command_inside_a_precomputed_chunk_takes_effect_at_its_time():
    """The cell computes samples ahead; a valve command must still act exactly at
    t + switching delay, never earlier, never later."""

    async def body():
        backend = _sim(1, CylinderScene(diameter_mm=60))
        cell = backend.sim
        async with backend:
            await backend.regulator.set_setpoint(63e3, 0.0)
            await backend.valves.set("supply", True, 0.0)
            while cell.t_next < 10.0:
                await backend.source.read_block()
            await backend.valves.set("supply", False, cell.t_last)
            for _ in range(3):
                await backend.source.read_block()
            t_cmd = cell.t_last
            await backend.valves.set("actuate", True, t_cmd)
            trace = []
            for _ in range(10):
                blk = await backend.source.read_block()
                trace.append((blk.t, cell._cache_true[cell._cache_pos - len(blk): cell._cache_pos, 0]))
        t = np.concatenate([x[0] for x in trace])
        p = np.concatenate([x[1] for x in trace])
        return t_cmd, t, p

    t_cmd, t, p = asyncio.run(body())
    delay = Hardware().circuit.valve_delay_s
    before = t <= t_cmd + delay + 1e-9
    assert np.all(np.abs(p[before]) < 1e-6)
    assert p[~before][0] > 0  # the first sample after the valve opened sees flow
