"""The sampler's config and its accounting of blocks dropped on a full queue, in this process.
(The sampler process for real, at 1 kHz: tests/system/test_sampler_process.py.)"""

from __future__ import annotations

import pydantic
import pytest
from fluidsense.drivers.sampler import SampledSource, SamplerConfig

SYNTHETIC = "fluidsense.drivers.sampler.synthetic:SyntheticPoller"


def config(**changes) -> SamplerConfig:
    data = {"poller": {"factory": SYNTHETIC, "kwargs": {"channels": 2, "amplitude_pa": 5000.0}},
            "channels": ["p_act", "p_tank"], "rate_hz": 1000, "block_size": 10,
            "silence_timeout_s": 10.0}
    data.update(changes)
    return SamplerConfig.model_validate(data)


@pytest.mark.parametrize("changes, message", [
    ({"late_threshold_us": 1000.0}, r"late_threshold_us \(1000\) must be below the period"),
    ({"spin_us": 1500.0, "rate_hz": 1000}, r"spin_us \(1500\) must be below the period"),
    ({"rate_hz": 0}, "greater than 0"),
    ({"block_size": 0}, "greater than or equal to 1"),
    ({"cpu": -1}, "cpu"),
    ({"rt_priority": 100}, "less than or equal to 99"),
    ({"channels": ["a", "a"]}, "unique"),
    ({"poller": {"factory": "no colon here"}}, "String should match pattern"),
    ({"poller": {"factory": SYNTHETIC, "kwargz": {}}}, "Extra inputs are not permitted"),
    ({"rate": 1000}, "Extra inputs are not permitted"),
])
def test_config_is_strict(changes, message):
    with pytest.raises(pydantic.ValidationError, match=message):
        config(**changes)


class FakePush:
    """A PUSH socket whose queue is full for the first ``full`` messages."""

    def __init__(self, full: int) -> None:
        self.full = full
        self.sent: list[list] = []

    def send_multipart(self, frames, flags=0):
        import zmq

        if self.full:
            self.full -= 1
            raise zmq.Again()
        self.sent.append([bytes(f) for f in frames])


def test_blocks_dropped_on_a_full_queue_are_accounted_for_in_the_next_one():
    from array import array

    from fluidsense.drivers.sampler.process import Sender
    from fluidsense.drivers.sampler.slots import Block, Counts
    from fluidsense.drivers.sampler.wire import decode

    def block(seq, begin, end, counts, n):
        return Block(seq, begin, end, counts, array("d", [begin / 1e3 + i / 1e3 for i in range(n)]),
                     array("d", [1.0] * n), array("d", [0.0] * n), 0.0)

    sock = FakePush(full=2)
    sender = Sender(sock, heartbeat_ns=10**9)
    sender.block(block(0, 0, 12, Counts(on_time=9, late=1, missed=2), 10))   # dropped
    sender.block(block(1, 12, 23, Counts(on_time=10, failed=1), 10))         # dropped
    sender.block(block(2, 23, 33, Counts(on_time=8, late=2), 10))            # sent
    assert sender.dropped_blocks == 2 and sender.dropped_samples == 20
    header, frames = decode(sock.sent[0])
    assert (header["slot_begin"], header["slot_end"]) == (0, 33)
    counts = tuple(header[k] for k in ("on_time", "late", "missed", "failed", "dropped"))
    assert counts == (8, 2, 2, 1, 20)
    assert header["on_time"] + header["late"] + header["missed"] + header["failed"] + header["dropped"] == 33
    # the daemon turns it into a block whose missed counts every slot without a sample here
    src = SampledSource(config(channels=["p_act"]))
    out = src._to_block(header, frames)
    assert len(out) == 10 and out.missed == 23 and out.late == 2
    assert src.stats["slots"] == 33 and src.stats["dropped"] == 20
