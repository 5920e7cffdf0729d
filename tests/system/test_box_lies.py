"""A control box that lies on the wire: RTDE analog inputs that read NaN, infinity or a
value no input can measure, a timestamp that jumps 1000 s ahead, runs back, runs ten times
fast or stands still, a Modbus reply with one register too many or too few or an analog
input domain register that reads no domain. Each lie is one
``driver`` fault that names the field, the valves go to their safe state (read back from the
box), the link is connected again, ``reset`` works once the box is sane, and the sample
stream moves on. A timestamp that stands still is a silent robot, not a lie: a ``link_lost``
fault, with the same recovery.

The box is the emulator (``fluidsense simcell``) with its real RTDE and pymodbus servers,
the daemon the real one with ur_rtde and pymodbus clients; the lie is the box's own (sim
control ``lie``, simulator/controlbox/lies.py), told in a counted number of packages or
replies. Nothing is mocked, and nothing waits on the wall clock: waits are for messages,
for samples and for the box's state.

(Its in-process tests: tests/unit/test_box_lies.py.)
"""

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
    ("modbus", "modbus_extra", "driver", "registers:", 4),
    ("modbus", "modbus_short", "driver", "registers:", 4),
    ("modbus", "modbus_domain", "driver", "register 5:", 4),
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


def test_an_analog_input_domain_changed_mid_run_is_a_driver_fault_naming_the_register_then_set_up_refuses_it(
        tmp_path):
    """The box's analog input 0 is set to current mid-run (the wiring's sensor outputs
    volts): the poll that reads the domain register (5, read with the inputs at every
    poll) ends the session with a ``driver`` fault naming the register and the domain
    expected, before the input's reading (0 mA: the sensor's rail) can be a pressure, and
    the valves are vented as the box reports. While the box stays so, reconnecting is
    refused by the set-up check; set back, the cell reconnects and ``reset`` works (the
    set-up check's refusal: tests/system/test_drivers.py)."""
    with free_simcell(tmp_path, "modbus", profile="sorting-gripper-quick.yaml", driver={**QUICK, "arm": None},
                      supervision=SUPERVISION) as (box, cell):
        d = Daemon(cell)
        watch = Watch(d)
        try:
            d.wait_welcome(timeout_s=120)
            watch.samples_past(500)
            assert box.command({"cmd": "set", "analog_input": {"channel": 0, "domain": "CURRENT"}})["ok"]
            fault = watch.until(lambda topic, _: topic == "fault", within_s=60)
            assert fault["kind"] == "driver", fault
            assert "register 5: analog input 0's domain changed to 0 (current) mid-run; expected 1 (voltage" \
                in fault["detail"], fault
            assert fault["vented"] is True, fault
            box.wait_for(lambda s: s["digital_outputs"] & 0b11 == SAFE, 30, "the safe outputs")
            assert box.command({"cmd": "set", "analog_input": {"channel": 0, "domain": "VOLTAGE"}})["ok"]
            watch.samples_past(100)
            assert d.request({"cmd": "reset"})["ok"]
            status = watch.samples_past(1500)
            assert watch.faults[1:] == [], watch.faults
            assert status["fault"] is None and status["state"] == "idle", status
        finally:
            assert d.close() == 0


#: supervision.freeze_s and stuck_s as shipped (controller/config/cell.py)
FREEZE_S, STUCK_S = 0.05, 0.25


def _measure(d: Daemon, watch: Watch, **request) -> tuple[dict, dict]:
    """One ``measure``: its ``grasp`` and ``cycle`` events."""
    started = d.request({"cmd": "measure", **request})
    assert started["ok"], started
    got: dict[str, dict] = {}
    watch.until(lambda topic, msg: msg.get("cycle_id") == started["cycle_id"] and topic in ("grasp", "cycle")
                and got.setdefault(topic, msg) is not None and len(got) == 2, within_s=120)
    return got["grasp"], got["cycle"]


def test_a_freeze_shorter_than_stuck_s_inside_the_window_marks_the_reading_unreliable(tmp_path):
    """The box's inputs stand still for 100 I/O cycles (0.2 s, under the supervisor's 0.25 s
    stuck_s) from 0.45 s after the actuation valve opens: across the 0.5-0.55 s window.
    No fault, but the cycle and the grasp say that the reading is unreliable, naming the
    channel and the window. The free-air measure before it, through the same box, repeats
    a reading for far less than freeze_s: the box's normal repeats are not a freeze."""
    with free_simcell(tmp_path, "modbus", profile="sorting-gripper-quick.yaml", driver={**QUICK, "arm": None},
                      supervision=SUPERVISION, gripper={}) as (box, cell):
        d = Daemon(cell)
        watch = Watch(d)
        try:
            d.wait_welcome(timeout_s=120)
            grasp, cycle = _measure(d, watch, store_reference=True)
            assert cycle["ok"] and cycle["unreliable"] is None and grasp["unreliable"] is None, cycle
            assert cycle["unchanged_s"] < FREEZE_S, cycle
            told = box.command({"cmd": "lie", "kind": "freeze", "count": 100, "on_output": 1, "delay_s": 0.45})
            assert told["ok"] and told["lies"]["armed"] == "freeze", told
            grasp, cycle = _measure(d, watch)
            assert cycle["ok"] and FREEZE_S <= cycle["unchanged_s"] < STUCK_S, cycle
            assert cycle["unreliable"].startswith("p_act read ") and "in window eq" in cycle["unreliable"], cycle
            # the grasp comes as the window closes, while the freeze still holds: the run so far
            assert grasp["unreliable"].startswith("p_act read ") and "in window eq" in grasp["unreliable"], grasp
            lies = box.command({"cmd": "state"})["lies"]
            assert lies["kind"] is None and lies["armed"] is None and lies["told"] == 100, lies
            assert watch.faults == [], watch.faults
        finally:
            assert d.close() == 0
