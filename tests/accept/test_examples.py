"""The examples under examples/ against ``fluidsense simcell`` (the emulated UR control
box) and a daemon on config/cell-gripper-modbus-sim.yaml: they run, exit 0 and do what
they say. examples/README.md's shell block is run as written (its fenced ``sh`` lines, in
order). pick_and_place.py is the integrator's motion stack: it moves the box's arm with the
real ur_rtde while the daemon holds the grip, which makes it the test of holding while
the arm moves. ros2_gripper_node.py needs ROS 2: not run.

(Its tests with real peers: tests/system/test_examples.py.)
"""

from __future__ import annotations

import json
import re
import signal
import socket

import pytest
import yaml
from support.docs import run_as_written, shell_blocks
from support.harness import REPO, SIMCELL_PORTS, free_loopback, simcell_config

EXAMPLES = REPO / "examples"

# examples/README.md walked as written: a box, a daemon and the pick-and-place run in real
# time, a few minutes beside other work
pytestmark = pytest.mark.timeout(900)


def test_examples_readme_pick_and_place_runs_as_written(tmp_path):
    """examples/README.md's block, as written, from the repository's folder: the emulated
    box, the daemon, the example (it takes its own free-air reference and lays the object
    in the emulated world). Only the config's path is replaced, as the README says, by a
    copy on a free loopback address (RTDE ports are fixed). The example moves the arm with
    the real ur_rtde while the daemon holds the grip: the test of holding while it moves."""
    (block,) = shell_blocks(EXAMPLES / "README.md")
    assert any("pick_and_place.py" in line for line in block), block
    cell = simcell_config(tmp_path, "gripper-modbus", free_loopback(SIMCELL_PORTS))
    data = yaml.safe_load(cell.read_text())
    background, results = run_as_written(block, {"config/cell-gripper-modbus-sim.yaml": str(cell)}, tmp_path)
    def logs() -> str:  # the box's and the daemon's, for a failure's message
        return "\n".join((tmp_path / f"bg{i}.log").read_text() for i in range(len(background)))

    try:
        (out,) = results
        assert out.returncode == 0, out.stdout + out.stderr + "\n--- box and daemon:\n" + logs()[-6000:]
        assert "free-air reference taken" in out.stdout and "arm: retract" in out.stdout, out.stdout
        line = next(x for x in out.stdout.splitlines() if x.startswith("grasp:"))
        value, lo, hi = (float(v) for v in re.search(r"diameter ([\d.]+) mm \[([\d.]+), ([\d.]+)\]", line).groups())
        assert "object True" in line and value == pytest.approx(60, abs=2), line
        print(f"60 mm cylinder read as {value} mm [{lo}, {hi}]")  # the interval's coverage: see the report
        world = sim_control(data["driver"]["host"], data["driver"]["sim_control_port"], {"cmd": "truth"})
    finally:
        codes = []
        for proc, log in reversed(background):  # the daemon first: it vents, then the box
            proc.send_signal(signal.SIGTERM)  # as `kill %1 %2` does
            codes.append(proc.wait(60))
            log.close()
    assert codes == [0, 0], logs()
    assert "Traceback" not in logs(), logs()
    world = world["truth"]["world"]
    # the box's world: closed at the pick slot, carried (held well enough to lift), opened at the place slot
    assert world["content"] == {"pick": None, "place": "cylinder"} and world["holding"] is None
    kinds = [(e["event"], e.get("slot"), e.get("object")) for e in world["events"]]
    assert ("close", "pick", "cylinder") in kinds and ("open", "place", "cylinder") in kinds
    assert [e["event"] for e in world["events"]].count("picked") == 1
    assert not any(e["event"] in ("not_held", "dropped", "slipped") for e in world["events"]), world["events"]


def sim_control(host: str, port: int, request: dict) -> dict:
    with socket.create_connection((host, port), timeout=30) as sock:
        sock.sendall(json.dumps(request).encode() + b"\n")
        return json.loads(sock.makefile().readline())
