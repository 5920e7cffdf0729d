"""Looking without touching: sample the cell for a few seconds and judge what comes
back (rate, gaps, lateness, each channel's level, noise and liveliness, the valve
outputs as the device reports them) against the config and the profile."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass

import numpy as np
from fluidsense.common.samples import SampleBlock
from fluidsense.common.units import KPA
from fluidsense.drivers.backend import Backend

from .findings import Findings

#: delivered below this share of the configured rate, or more slots missed than this share:
#: a problem on a PC with CPU to spare
RATE_SHARE, MISSED_SHARE = 0.9, 0.1
#: delivered below this share, or more slots missed than 1 - this share: a problem even on a
#: busy PC. A busy PC (or an emulated box sharing two loaded cores with the check) loses a
#: fraction of the slots: `fluidsense check` on the emulated box got 354-446 of 500
#: samples/s at a load average of 2.7 per CPU (2 shared cores). A broken link or a wrong
#: rate loses most: a CB3 (125 Hz) configured as e-Series delivers 25 %.
BROKEN_SHARE = 0.5
#: the PC counts as busy from this 1-minute load average per CPU (every core has a
#: runnable task waiting besides the one running)
BUSY_LOAD_PER_CPU = 1.0
#: measured noise above this multiple of the profile's is a problem
NOISE_FACTOR = 3.0
#: the last samples of a step over which a level is taken (s)
LEVEL_S = 0.05


class Rig:
    """Reads the backend's blocks and kicks the box watchdog as the daemon's sample loop
    does (four times per timeout of sample time), so a box that watches for the
    heartbeat keeps its outputs while the check moves them."""

    def __init__(self, backend: Backend, kick: bool) -> None:
        self.backend = backend
        self.kick = kick and backend.watchdog is not None
        self.now = float("nan")
        self._next_kick = -float("inf")

    async def block(self) -> SampleBlock:
        block = await self.backend.source.read_block()
        self.now = block.t_end
        if self.kick and self.now >= self._next_kick:
            self._next_kick = self.now + self.backend.watchdog.timeout_s / 4
            await self.backend.watchdog.kick()
        return block

    async def collect(self, seconds: float) -> list[SampleBlock]:
        """Blocks covering ``seconds`` of sample time from now."""
        first = await self.block()
        blocks = [first]
        while blocks[-1].t_end < first.t[0] + seconds:
            blocks.append(await self.block())
        return blocks

    async def level(self, seconds: float) -> dict[str, float]:
        """Each channel's mean (Pa) over the last LEVEL_S of ``seconds`` of samples."""
        blocks = await self.collect(seconds)
        t = np.concatenate([b.t for b in blocks])
        values = np.concatenate([b.values for b in blocks])
        recent = values[t >= t[-1] - LEVEL_S]
        return {ch: float(np.nanmean(recent[:, i])) for i, ch in enumerate(blocks[0].channels)}


@dataclass(frozen=True)
class Sampling:
    channels: tuple[str, ...]
    values: np.ndarray  # samples x channels, Pa
    samples: int
    missed: int
    late: int
    wall_s: float
    span_s: float
    delays_s: np.ndarray  # real time: block arrival after its last sample's time


async def sample(rig: Rig, seconds: float) -> Sampling:
    """``seconds`` of samples after a first block (which carries the start-up's slots)."""
    source = rig.backend.source
    await rig.block()
    start = time.monotonic()
    blocks, delays = [], []
    first_t = None
    while first_t is None or blocks[-1].t_end < first_t + seconds:
        block = await rig.block()
        if source.clock_origin_s is not None:
            delays.append(time.monotonic() - (source.clock_origin_s + block.t_end))
        first_t = block.t[0] if first_t is None else first_t
        blocks.append(block)
    wall = time.monotonic() - start
    return Sampling(channels=blocks[0].channels, values=np.concatenate([b.values for b in blocks]),
                    samples=sum(len(b) for b in blocks), missed=sum(b.missed for b in blocks),
                    late=sum(b.late for b in blocks), wall_s=wall, span_s=blocks[-1].t_end - first_t,
                    delays_s=np.asarray(delays))


def load_per_cpu() -> float | None:
    """The PC's 1-minute load average per CPU (None where the OS does not say)."""
    try:
        return os.getloadavg()[0] / (os.cpu_count() or 1)
    except (AttributeError, OSError):
        return None


def judge_rate(s: Sampling, rate_hz: float, virtual: bool, out: Findings, load: float | None = None) -> None:
    """A shortfall is a problem below RATE_SHARE of the rate (or over MISSED_SHARE of the
    slots missed) when the PC has CPU to spare, and below BROKEN_SHARE whatever the load:
    a busy PC delays and drops some slots, a broken link or a wrong rate most of them.
    ``load``: the PC's load average per CPU during the sampling (None: unknown, not busy)."""
    slots = s.samples + s.missed
    if virtual:
        out.info(f"virtual clock: {s.samples} samples over {s.span_s:.2f} s of sample time at {rate_hz:g} Hz "
                 f"({s.wall_s:.2f} s of wall time)")
        return
    delivered = s.samples / s.wall_s
    out.info(f"delivered {delivered:.0f} samples/s of the configured {rate_hz:g} Hz over {s.wall_s:.1f} s: "
             f"{s.missed} slots missed, {s.late} samples late")
    if len(s.delays_s):
        p50, p99 = np.percentile(s.delays_s, [50, 99]) * 1e3
        out.info(f"block delivery after its last sample: median {p50:.1f} ms, p99 {p99:.1f} ms, "
                 f"max {s.delays_s.max() * 1e3:.1f} ms")
    short = delivered < RATE_SHARE * rate_hz or s.missed > MISSED_SHARE * slots
    broken = delivered < BROKEN_SHARE * rate_hz or s.missed > (1 - BROKEN_SHARE) * slots
    busy = load is not None and load >= BUSY_LOAD_PER_CPU
    if short and busy and not broken:
        out.info(f"short of {RATE_SHARE:.0%} of the rate, but the PC is busy (load average {load:.1f} per CPU): "
                 f"not held against the link above {BROKEN_SHARE:.0%}; check again on an unloaded PC")
    elif short:
        out.problem("sampling", f"the device delivers {delivered:.0f} of {rate_hz:g} samples/s ({s.missed} of "
                    f"{slots} slots missed)", "lower driver.rate_hz (a CB3 gives 125 Hz over RTDE), use a wired "
                    "link without other traffic, or unload the PC (docs/performance.md)")


def _signal(driver, channel: str, p_pa: float) -> str:
    """The electrical signal a channel's sensor gives at ``p_pa``, through the wiring's
    transfer (the sim driver has no wiring)."""
    wiring = getattr(driver, "wiring", None)
    if wiring is None or channel not in wiring.sensors:
        return ""
    s = wiring.sensors[channel]
    sig = s.transfer.to_signal(p_pa)
    text = f"AI{s.analog_input} {sig:.3f} V" if s.transfer.domain == "voltage" else \
        f"AI{s.analog_input} {sig * 1e3:.2f} mA"
    lo, hi = driver.analog.span(s.transfer.domain)
    if sig <= lo + 1e-3 * (hi - lo) or sig >= hi - 1e-3 * (hi - lo):
        text += " (at the input's limit)"
    return text + " -> "


def judge_channels(s: Sampling, cfg, vented: bool, zero_kpa: float, out: Findings) -> None:
    """Each channel: level, noise (from sample-to-sample differences: a slow drift is not
    noise), liveliness and range against the profile; the actuator's sensor must read
    about 0 kPa gauge when the actuator is vented."""
    hw, driver = cfg.profile.hardware, cfg.driver
    for i, ch in enumerate(s.channels):
        v = s.values[:, i]
        if ch == "flow":
            out.info(f"flow: mean {np.nanmean(v) * 6e4:.3f} SLPM")
            continue
        sensor = hw.sensor if ch == "p_act" else hw.tank_sensor
        finite = v[np.isfinite(v)]
        if len(finite) < len(v):
            out.problem(ch, f"{len(v) - len(finite)} of {len(v)} samples are not numbers",
                        f"the sensor or its analog input is dead: check its cable, supply and wiring.sensors.{ch}")
            if not len(finite):
                continue
        mean_kpa = float(np.mean(finite)) / KPA
        noise_kpa = float(np.std(np.diff(finite)) / np.sqrt(2)) / KPA
        out.info(f"{ch}: {_signal(driver, ch, float(np.mean(finite)))}{mean_kpa:+.2f} kPa, noise {noise_kpa:.3f} kPa "
                 f"(profile: offset {sensor.offset_kpa:+.2f}, noise {sensor.noise_sd_kpa:.3f} kPa), "
                 f"range seen [{finite.min() / KPA:+.2f}, {finite.max() / KPA:+.2f}] kPa")
        lo, hi = sensor.range_kpa
        if np.ptp(finite) == 0 and len(finite) >= 10:
            out.problem(ch, f"stuck: every one of {len(finite)} samples reads {mean_kpa:+.3f} kPa exactly",
                        "a live sensor always shows some noise: check its supply and cable, and that the input is "
                        f"the one in wiring.sensors.{ch}")
        elif not lo <= mean_kpa <= hi:
            out.problem(ch, f"reads {mean_kpa:+.2f} kPa, outside the sensor's range [{lo:g}, {hi:g}] kPa",
                        f"a saturated, unpowered or disconnected sensor, or a wrong transfer in wiring.sensors.{ch}")
        elif ch == "p_act" and vented and abs(mean_kpa) > zero_kpa:
            out.problem(ch, f"reads {mean_kpa:+.2f} kPa with the actuator vented (expected 0 +- {zero_kpa:g} kPa "
                        "gauge)", f"check the transfer in wiring.sensors.{ch} (range, supply_v), the sensor's zero, "
                        "and that the gripper really is vented")
        elif noise_kpa > NOISE_FACTOR * max(sensor.noise_sd_kpa, sensor.quantum_kpa):
            out.problem(ch, f"noise {noise_kpa:.3f} kPa, over {NOISE_FACTOR:g}x the profile's "
                        f"{sensor.noise_sd_kpa:.3f} kPa", "the detection thresholds assume the profile's noise: check "
                        "grounding and shielding, or measure and set the profile's sensor noise_sd_kpa")


async def judge_valves(backend: Backend, venting: tuple[str, ...], out: Findings) -> bool | None:
    """The valve outputs as the device reports them; True when the actuator is vented
    (every valve in ``venting`` at its safe position), None when the device cannot report
    them. A valve that only isolates the tank (supply) may rest with its output off, away
    from its safe position: a normally-open supply valve is open on a box just powered
    up or after its watchdog fired, with the actuator vented; the daemon closes it when it
    connects. Any other valve away from its safe position is held by something."""
    valves = backend.valves
    positions = await valves.read_back()
    if positions is None:
        out.info("valves: this device cannot report its outputs")
        return None
    wiring = getattr(valves, "wiring", None)
    for name, is_open in positions.items():
        w = wiring.get(name) if wiring is not None else None
        where = f" (output {w.output})" if getattr(w, "output", None) is not None else ""
        safe = valves.safe_positions[name]
        state = "open" if is_open else "closed"
        if is_open == safe:
            out.info(f"valve {name}{where}: {state}, its safe position")
        elif name not in venting and w is not None and not w.level(is_open):
            out.info(f"valve {name}{where}: {state}, its output off (at rest, as after power-up or the box's "
                     f"watchdog); its safe position is {'open' if safe else 'closed'}, which the daemon sets when "
                     "it connects")
        else:
            out.problem(f"valve {name}{where}", f"the device reports it {state}; its safe position is "
                        f"{'open' if safe else 'closed'}", "something holds it (a running daemon, a program on "
                        "the box, the pendant): stop it, or run `fluidsense check --actuate`, which starts by "
                        "venting")
    return all(positions.get(v) == valves.safe_positions[v] for v in venting if v in positions)
