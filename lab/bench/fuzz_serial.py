"""The serial device-side fuzz: frames with a valid CRC and hostile contents, fed to the
serial driver's link as the port's bytes.

Each case is one session as a device would run it: START acknowledged, a few sane sample
frames (ticks 0, 1, 2, ...), then frames drawn by hypothesis: sample frames with any
session, seq, tick, outputs, flags, late_us, analog outputs and 0-12 counts of any value,
often near the truth (the next tick, the next seq, the right session: one field off);
ACKs and INFOs with any fields; unknown frame types; and repeats. Every frame is CRC-framed
as the firmware does (``protocol.frame``) and written to a pipe that the link reads with
the code that reads the port (``reader: loop``), so everything from the splitter on is
the driver's own. What must hold, whatever the device says:

- nothing raises out of the link's read: a frame is a sample, a count of damage, or an
  error queued for the sample loop;
- a session ends at most once: after a DeviceProtocolError (its ``field`` one of counts,
  tick, rate, seq) or a DeviceResetError, nothing more is queued;
- every error queued is a DriverError (a ``driver`` or ``link_lost`` fault, never an
  internal one);
- every block delivered has finite pressures in the configured shape, slots strictly
  increasing within and across blocks, and sample time never ahead of the host clock by
  more than the guard allows (a device cannot move the daemon's sample time into the future).

``fuzz_serial(examples, seed)`` returns the counts; ``case_strategy()`` is what
tests/unit/test_serial_protocol.py runs at a small budget in the suite.
"""

from __future__ import annotations

import argparse
import json
import os
import struct
import time
from collections import Counter
from typing import Any

import numpy as np
from fluidsense.common.errors import DeviceProtocolError, DriverError
from fluidsense.common.samples import SampleBlock
from fluidsense.drivers.clockcheck import MAX_CLOCK_ERROR
from fluidsense.drivers.serial import protocol as p
from fluidsense.drivers.serial.backend import count_scale
from fluidsense.drivers.serial.clock import Timeline
from fluidsense.drivers.serial.config import SerialDriverConfig
from fluidsense.drivers.serial.link import SerialLink
from fluidsense.drivers.serial.stream import LEAD_MARGIN_S, DeviceResetError

NAME = "fuzz-serial"
HELP = "a serial device's frames with a valid CRC and hostile contents against the driver's link"
DESCRIPTION = __doc__

SESSION = 7
SANE = 25  # good sample frames before each case (ticks 0-24, seq 1-25)
CHANNELS = ("p_act", "p_tank")
FIELDS = ("counts", "tick", "rate", "seq")


def driver_config() -> SerialDriverConfig:
    """The shipped serial config's driver (config/cell-serial-sim.yaml), without a port to open."""
    import yaml  # noqa: PLC0415 - a study's import

    from lab import CONFIG  # noqa: PLC0415

    data = yaml.safe_load((CONFIG / "cell-serial-sim.yaml").read_text())["driver"]
    data.pop("sim_control_port", None)
    return SerialDriverConfig.model_validate(data)


def sample(session: int, seq: int, tick: int, counts: tuple[int, ...], outputs: int = 1, flags: int = 1,
           late: int = 0, aout: tuple[int, int] = (0, 0)) -> bytes:
    head = struct.pack("<BBHIBBBHH", p.SAMPLE, session, seq & 0xFFFF, tick & 0xFFFFFFFF, outputs, flags, late, *aout)
    return head + struct.pack(f"<{len(counts)}H", *counts)


def case_strategy():
    """A case: the payloads (CRC not yet added) a hostile device sends after START."""
    from hypothesis import strategies as st  # noqa: PLC0415 - hypothesis is a test extra

    u8, u16, u32 = st.integers(0, 0xFF), st.integers(0, 0xFFFF), st.integers(0, 0xFFFFFFFF)
    counts = st.lists(u16, max_size=12).map(tuple)
    sane_counts = st.lists(st.integers(0, 1023), min_size=2, max_size=2).map(tuple)

    @st.composite
    def frames(draw) -> list[bytes]:
        out: list[bytes] = []
        seq, tick = SANE + 1, SANE  # the case goes on from the good frames before it
        for _ in range(draw(st.integers(1, 40))):
            kind = draw(st.sampled_from(["near"] * 5 + ["burst"] * 4 + ["sample", "ack", "info", "other", "repeat"]))
            if kind == "burst":  # a run of good frames, faster than any timer (they arrive at once)
                for _ in range(draw(st.integers(100, 600))):
                    out.append(sample(SESSION, seq, tick, (512, 512)))
                    seq, tick = seq + 1, tick + 1
            elif kind == "near":  # the next frame with one field off (or none)
                fields = {"session": SESSION, "seq": seq, "tick": tick, "counts": draw(sane_counts)}
                off = draw(st.sampled_from([None, "session", "seq", "tick", "counts", "flags"]))
                if off == "session":
                    fields["session"] = draw(u8)
                elif off == "seq":
                    fields["seq"] = seq + draw(st.integers(-3, 70_000))
                elif off == "tick":
                    fields["tick"] = tick + draw(st.one_of(st.integers(-2, 5), st.integers(6, 2**32)))
                elif off == "counts":
                    fields["counts"] = draw(counts)
                flags = draw(u8) if off == "flags" else 1
                out.append(sample(fields["session"], fields["seq"], fields["tick"], fields["counts"], flags=flags))
                seq, tick = fields["seq"] + 1, fields["tick"] + 1
            elif kind == "sample":
                out.append(sample(draw(st.one_of(st.just(SESSION), u8)), draw(u16), draw(u32), draw(counts), draw(u8),
                                  draw(u8), draw(u8), (draw(u16), draw(u16))))
            elif kind == "ack":
                out.append(struct.pack("<BBHBHBIBB", p.ACK, draw(st.sampled_from([SESSION, SESSION, 0])), draw(u16),
                                       draw(u8), draw(u16), draw(u8), draw(u32), draw(u8), draw(u8)))
            elif kind == "info":
                out.append(struct.pack("<BBHB8sBBBBHHBHH", p.INFO, draw(st.sampled_from([SESSION, SESSION, 0])), draw(u16),
                                       draw(u8), draw(st.binary(min_size=8, max_size=8)), draw(u8), draw(u8),
                                       draw(u8), draw(u8), draw(u16), draw(u16), draw(u8), draw(u16), draw(u16)))
            elif kind == "other":
                out.append(bytes([draw(u8)]) + draw(st.binary(max_size=40)))
            elif out:
                out.append(out[-1])
        return out

    return frames()


class Run:
    """One case against a fresh link: START acknowledged, ``sane`` good samples, then the case."""

    def __init__(self, cfg: SerialDriverConfig, sane: int = SANE):
        self.cfg = cfg
        self.timeline = Timeline(cfg.rate_hz)
        mask, order, gain, offset = count_scale(cfg, CHANNELS)
        self.link = SerialLink(cfg, self.timeline, CHANNELS, mask, order, gain, offset)
        self.link.session, self.link.delivering = SESSION, True
        self.sane = sane
        self.started = time.monotonic()

    def feed(self, payloads: list[bytes]) -> None:
        r, w = os.pipe()
        try:
            for chunk in self._chunks(payloads):
                os.write(w, chunk)
                if not self.link._read(r):  # noqa: SLF001 - the port's read path, fed by a pipe
                    raise AssertionError("the link stopped reading a pipe that is still open")
        finally:
            os.close(r)
            os.close(w)

    def _chunks(self, payloads: list[bytes]):
        start = struct.pack("<BBHBHBIBB", p.ACK, SESSION, 0, p.START, 0, p.OK, p.NO_TICK, 0, 0)
        good = [sample(SESSION, 1 + i, i, (512, 512)) for i in range(self.sane)]
        data = b"".join(p.frame(x) for x in [start, *good])
        yield data
        chunk = b""  # as a device floods a port: whatever fits a read arrives at once
        for x in payloads:
            framed = p.frame(x) if len(x) + 2 <= p.MAX_FRAME else p.frame(x[:p.MAX_FRAME - 2])
            if len(chunk) + len(framed) > 60_000:
                yield chunk
                chunk = b""
            chunk += framed
        if chunk:
            yield chunk

    def check(self) -> dict[str, Any]:
        """The properties (module docstring); what the case did."""
        items: list[Any] = []
        while not self.link.queue.empty():
            items.append(self.link.queue.get_nowait())
        ended = [i for i, x in enumerate(items) if isinstance(x, (DeviceProtocolError, DeviceResetError))]
        assert len(ended) <= 1, f"a session ended {len(ended)} times: {items}"
        if ended:
            assert ended[0] == len(items) - 1, f"queued after the session ended: {items[ended[0] + 1:]}"
        last_slot = -1
        for x in items:
            if isinstance(x, BaseException):
                assert isinstance(x, DriverError), f"not a driver error: {x!r}"
                if isinstance(x, DeviceProtocolError):
                    assert x.field in FIELDS, x
                continue
            assert isinstance(x, SampleBlock), x
            assert x.values.shape == (len(x), len(CHANNELS)) and np.all(np.isfinite(x.values)), x.values
            slots = np.rint(np.asarray(x.t) * self.cfg.rate_hz).astype(np.int64)
            assert np.all(np.diff(slots) > 0) and slots[0] > last_slot, (last_slot, slots)
            last_slot = int(slots[-1])
        guard = self.link._guard  # noqa: SLF001
        elapsed = time.monotonic() - self.started
        bound = elapsed * (1 + MAX_CLOCK_ERROR) + (guard.first_lead_s if guard else 0) + LEAD_MARGIN_S
        assert self.timeline.k_last / self.cfg.rate_hz <= bound, (self.timeline.k_last, bound)
        end = items[ended[0]] if ended else None
        return {"blocks": sum(isinstance(x, SampleBlock) for x in items),
                "ended": None if end is None else getattr(end, "field", "reset"),
                "errors": sum(isinstance(x, BaseException) for x in items) - len(ended)}


def fuzz_serial(examples: int, seed: int) -> dict[str, Any]:
    """``examples`` cases: counts of what they did; failures (property violated, or
    anything raised) listed with their first frames."""
    from hypothesis import HealthCheck, Phase, given, settings  # noqa: PLC0415
    from hypothesis import seed as with_seed  # noqa: PLC0415

    cfg = driver_config()
    counts: Counter[str] = Counter()
    failures: list[str] = []
    t0 = time.perf_counter()

    @with_seed(seed)
    @settings(max_examples=examples, database=None, deadline=None, phases=[Phase.generate],
              suppress_health_check=list(HealthCheck))
    @given(payloads=case_strategy())
    def one(payloads: list[bytes]) -> None:
        counts["cases"] += 1
        counts["frames"] += len(payloads)
        run = Run(cfg)
        try:
            run.feed(payloads)
            out = run.check()
        except Exception as exc:  # noqa: BLE001 - a failure is a figure, listed
            counts["failures"] += 1
            if len(failures) < 20:
                failures.append(f"{type(exc).__name__}: {exc} <- {[x.hex() for x in payloads[:5]]}")
            return
        counts["blocks"] += out["blocks"]
        counts["other_driver_errors"] += out["errors"]
        counts[f"ended_{out['ended']}" if out["ended"] else "not_ended"] += 1

    one()
    return {**dict(counts), "failure_cases": failures, "seconds": time.perf_counter() - t0}


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("--cases", type=int, default=300, help="device sessions (default 300)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--json", action="store_true")


def run(args: argparse.Namespace) -> int:
    out = fuzz_serial(args.cases, args.seed)
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        ended = {k[6:]: v for k, v in out.items() if k.startswith("ended_")}
        print(f"serial device sessions: {out['cases']} ({out['frames']} hostile frames) in {out['seconds']:.0f} s: "
              f"{out.get('failures', 0)} failures; ended by {ended}, not ended {out.get('not_ended', 0)}; "
              f"{out.get('blocks', 0)} blocks delivered, {out.get('other_driver_errors', 0)} other driver errors")
        for case in out["failure_cases"]:
            print(f"  failure: {case}")
    return 1 if out.get("failures") else 0
