"""A control box that lies on the wire: RTDE analog inputs that read NaN, infinity or a
value no input can measure, a timestamp that jumps 1000 s ahead, runs back, runs ten times
fast or stands still, a Modbus reply with one register too many or too few. Each lie is one
``driver`` fault that names the field, the valves go to their safe state (read back from the
box), the link is connected again, ``reset`` works once the box is sane, and the sample
stream moves on. A timestamp that stands still is a silent robot, not a lie: a ``link_lost``
fault, with the same recovery.

The box is the emulator (``fluidsense simcell``) with its real RTDE and pymodbus servers,
the daemon the real one with ur_rtde and pymodbus clients; the lie is the box's own (sim
control ``lie``, simulator/controlbox/lies.py), told in a counted number of packages or
replies. Nothing is mocked, and nothing waits on the wall clock: waits are for messages,
for samples and for the box's state."""

from __future__ import annotations

import pytest
from support.harness import Daemon, free_simcell
from support.watch import Watch

pytestmark = pytest.mark.timeout(300)

#: room for a shared 2-core machine: the emulated box, the daemon, its sampler and the
#: ur_rtde worker share it with other work; what is tested is the lie's fault, not the
#: timing supervisors
SUPERVISION = {"overrun_s": 5.0, "no_data_s": 5.0}
QUICK = {"reconnect": {"first_s": 0.2, "max_s": 1.0, "connect_timeout_s": 15.0}}
SAFE = 0b01  # the sorting gripper's safe outputs: supply isolated (0 high), gripper vented (1 low)

CASES = [
    ("ur", "analog_nan", "driver", "standard_analog_input0:", 20),
    ("ur", "analog_inf", "driver", "standard_analog_input0:", 20),
    ("ur", "analog_range", "driver", "standard_analog_input0:", 20),
    ("ur", "timestamp_forward", "driver", "timestamp:", 20),
    ("ur", "timestamp_back", "driver", "timestamp:", 20),
    ("ur", "timestamp_fast", "driver", "timestamp:", 200),
    ("ur", "timestamp_stall", "link_lost", "stale", 1500),
    ("modbus", "modbus_extra", "driver", "registers:", 20),
    ("modbus", "modbus_short", "driver", "registers:", 20),
]


@pytest.mark.parametrize("kind, lie, fault_kind, field, count", CASES, ids=[c[1] for c in CASES])
def test_a_lying_box_is_one_fault_naming_the_field_then_reconnected_and_reset_works(
        tmp_path, kind, lie, fault_kind, field, count):
    driver = {**QUICK, "arm": None} if kind == "modbus" else QUICK
    with free_simcell(tmp_path, kind, profile="sorting-gripper-quick.yaml", driver=driver,
                      supervision=SUPERVISION) as (box, cell):
        d = Daemon(cell)
        watch = Watch(d)
        try:
            d.wait_welcome(timeout_s=120)
            watch.samples_past(500)
            told = box.command({"cmd": "lie", "kind": lie, "count": count})
            assert told["ok"] and told["lies"]["kind"] == lie, told
            fault = watch.until(lambda topic, _: topic == "fault", within_s=60)
            assert fault["kind"] == fault_kind and field in fault["detail"], fault
            # the safe state, as the box reports its outputs: to the daemon (its link to the
            # outputs stays up: only the sampler's session ends) and to the test
            assert fault["vented"] is True, fault
            box.wait_for(lambda s: s["digital_outputs"] & 0b11 == SAFE, 30, "the safe outputs")
            # the lie over, then samples again: a reconnection (it wrote and read back the safe positions)
            box.wait_for(lambda _: box.command({"cmd": "state"})["lies"]["kind"] is None, 60, "the lie's end")
            watch.samples_past(100)
            assert d.request({"cmd": "reset"})["ok"]
            status = watch.samples_past(1500)  # 3 s of samples after the reset: the stream moves
            assert watch.faults[1:] == [], watch.faults  # the lie made one fault, and nothing it left behind
            assert status["fault"] is None and status["state"] == "idle", status
            assert box.state()["digital_outputs"] & 0b11 == SAFE
        finally:
            assert d.close() == 0
