"""``python -m fluidsense.drivers.ur.worker ARGS_JSON``: ur_rtde's IO and control interfaces in a
process of their own.

ur_rtde's constructors hold the GIL while they wait for the robot (for ever when the
robot is silent) and its IO interface aborts its process when the robot goes away, so
neither may live in the daemon. This process owns them; the daemon (``link.py``)
talks to it with JSON lines on stdin/stdout and kills it when it stops answering.

Protocol. First line out: ``{"ready": true}`` or ``{"error": "..."}``. In:
``{"id": N, "op": OP, ...}`` with OP one of ``digital_out`` (output, level),
``analog_out`` (channel, domain, ratio), ``move_l`` (pose, speed, acc), ``stop_l``
(acc), ``ensure_program`` (upload the control script again if it stopped); out:
``{"id": N, "ok": true, ...}`` or ``{"id": N, "error": "..."}``. ``kick``
(no id, no answer) kicks the control script's RTDE watchdog, armed at ``watchdog_hz``
when the args give one: the script stops when the daemon stops asking for kicks. Every
``1/status_hz`` s, ``{"status": {...}}``: pose, digital outputs, safety mode, protective
stop, whether the control script runs, and the latest move's id and result
(``arrived``, ``stopped``). End of input: disconnect and exit 0.

Everything runs on one thread: ur_rtde's objects are not documented as thread-safe.
SIGINT and SIGTERM are ignored: the daemon vents through this process after a stop
signal that reached the whole process group, then closes its input.
"""

from __future__ import annotations

import json
import math
import os
import select
import signal
import sys
import threading
import time
from typing import Any

from fluidsense.drivers.child import exit_now, keep_until_exit

#: a finished move within this of its target arrived (UR's own blend-free tolerance is finer)
ARRIVED_M, ARRIVED_RAD = 1e-3, 1e-2
SCRIPT_START_S = 5.0  # ur_rtde waits as long for its script to run


class Worker:
    def __init__(self, args: dict[str, Any], out) -> None:
        self.args = args
        self.out = out
        self.receive = self.io = self.control = None
        self.move_id = 0
        self.move: dict[str, Any] | None = None  # the running move: id, target, since
        self.move_result: str | None = None
        self.watchdog_armed = False

    def connect(self) -> None:
        import rtde_receive  # noqa: PLC0415 - only in this process

        host, upper = self.args["host"], bool(self.args.get("upper_range_registers", False))
        self.receive = rtde_receive.RTDEReceiveInterface(host, float(self.args.get("status_hz", 50.0)),
                                                         ["timestamp", "actual_TCP_pose", "safety_mode", "safety_status_bits",
                                                          "runtime_state", "robot_mode",
                                                          "actual_digital_output_bits"], False, upper)
        if self.args.get("io", True):
            import rtde_io  # noqa: PLC0415

            self.io = rtde_io.RTDEIOInterface(host, False, upper)
        if self.args.get("control", True):
            import rtde_control  # noqa: PLC0415

            flags = rtde_control.RTDEControlInterface.Flags
            f = flags.FLAG_UPLOAD_SCRIPT | (flags.FLAG_UPPER_RANGE_REGISTERS if upper else 0)
            self.control = rtde_control.RTDEControlInterface(host, -1.0, f)

    # -- requests ------------------------------------------------------------------------------
    def handle(self, req: dict[str, Any]) -> dict[str, Any]:
        op = req.get("op")
        if op not in OPS:
            return {"id": req.get("id"), "error": f"unknown op {op!r}"}
        try:
            extra = getattr(self, f"_op_{op}")(req)
        except Exception as exc:  # noqa: BLE001 - answered, the worker goes on
            return {"id": req.get("id"), "error": f"{type(exc).__name__}: {exc}"}
        return {"id": req.get("id"), "ok": True, **(extra or {})}

    def _need(self, iface, what: str):
        if iface is None:
            raise RuntimeError(f"this worker has no {what} interface")
        return iface

    def _op_digital_out(self, req):
        io, n, level = self._need(self.io, "IO"), int(req["output"]), bool(req["level"])
        ok = io.setStandardDigitalOut(n, level) if n < 8 else io.setConfigurableDigitalOut(n - 8, level)
        if not ok:
            raise RuntimeError(f"digital output {n} not set")

    def _op_analog_out(self, req):
        io, ch, ratio = self._need(self.io, "IO"), int(req["channel"]), float(req["ratio"])
        if not 0.0 <= ratio <= 1.0:
            raise ValueError(f"analog output ratio {ratio} outside [0, 1]")
        ok = io.setAnalogOutputVoltage(ch, ratio) if req["domain"] == "voltage" else io.setAnalogOutputCurrent(ch, ratio)
        if not ok:
            raise RuntimeError(f"analog output {ch} not set")

    def _op_move_l(self, req):
        control = self._need(self.control, "control")
        self._ensure_script(control)
        pose = [float(v) for v in req["pose"]]
        # the script gives every async operation a new id in its progress register: the
        # move has started, in the control stream's own view, once the id differs from this
        op_before = control.getAsyncOperationProgressEx().operationId()
        if not control.moveL(pose, float(req["speed"]), float(req["acc"]), True):
            raise RuntimeError("moveL refused by the robot")
        self.move_id += 1
        self.move = {"id": self.move_id, "target": pose, "op_before": op_before}
        self.move_result = None
        return {"move_id": self.move_id}

    def _op_ensure_program(self, req):
        """The control script runs (uploaded again after its watchdog or a protective stop
        ended it): until it does, the box holds the valve outputs at their safe levels."""
        self._ensure_script(self._need(self.control, "control"))

    def _op_stop_l(self, req):
        control = self._need(self.control, "control")
        if control.isProgramRunning():
            control.stopL(float(req.get("acc", 2.0)), False)

    def _ensure_script(self, control) -> None:
        """After a protective stop the robot stops ur_rtde's script: upload it again."""
        if control.isProgramRunning():
            return
        control.reuploadScript()
        deadline = time.monotonic() + SCRIPT_START_S
        while not control.isProgramRunning():
            if time.monotonic() > deadline:
                raise RuntimeError("the control script does not run (robot not in remote control, or stopped?)")
            time.sleep(0.01)  # polling the robot's state, not a timing assumption
        self.watchdog_armed = False  # a new script starts without one

    def kick(self) -> None:
        """The daemon's heartbeat. The RTDE watchdog is armed at the first kick, not at
        connection: between the two the daemon still starts its sampler, and a watchdog
        armed early would stop the script before the daemon could ever kick it."""
        hz = self.args.get("watchdog_hz")
        if self.control is None or not hz:
            return
        try:
            if not self.watchdog_armed:
                self.control.setWatchdog(float(hz))
                self.watchdog_armed = True
            self.control.kickWatchdog()
        except Exception:  # noqa: BLE001, S110 - a lost robot shows in the next status
            pass

    # -- status --------------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        r = self.receive
        pose = list(r.getActualTCPPose())
        running = self.control.isProgramRunning() if self.control is not None else None
        if self.move is not None:
            self._follow_move(pose, running)
        return {"t": time.monotonic(), "connected": bool(r.isConnected()), "pose": pose,
                "digital_outputs": int(r.getActualDigitalOutputBits()),
                "safety_mode": int(r.getSafetyMode()), "protective_stop": bool(r.isProtectiveStopped()),
                "robot_mode": int(r.getRobotMode()), "program_running": running,
                "move_id": self.move_id, "move_result": self.move_result}

    def _follow_move(self, pose: list[float], running: bool | None) -> None:
        """Decide the running move's end from the control interface alone: its progress
        register says when the move ended, and the pose is asked from the script after that.
        The receive interface's pose is another RTDE stream, which on a busy PC can lag the
        control stream by more than a move's last few centimetres: judged by it, a move that
        arrived read as stopped short."""
        move, control = self.move, self.control
        if running:
            progress = control.getAsyncOperationProgressEx()
            if progress.operationId() == move["op_before"] or progress.isAsyncOperationRunning():
                return  # not seen to start yet, or still moving
            try:
                pose = list(control.getForwardKinematics())  # the actual TCP pose, now
            except Exception:  # noqa: BLE001 - e.g. the script just ended: judged at the next status
                return
        self.move_result = "arrived" if self._at(pose, move["target"]) else (
            "stopped" if running else "stopped: the control script ended")
        self.move = None

    @staticmethod
    def _at(pose: list[float], target: list[float]) -> bool:
        return (math.dist(pose[:3], target[:3]) <= ARRIVED_M
                and max(abs(a - b) for a, b in zip(pose[3:], target[3:])) <= ARRIVED_RAD)

    def emit(self, message: dict[str, Any]) -> None:
        self.out.write(json.dumps(message) + "\n")

    def close(self) -> None:
        """Disconnects every interface, at once: each disconnect waits about 0.5 s for its
        receiving thread, without holding the GIL, and a daemon stopping waits for this.
        The interfaces are then kept until the process ends (drivers/child.py): their
        destructors would wait as long again, one after the other."""
        if self.control is not None:
            # an orderly end: the script stops now (the box's run-state actions hold the
            # valves safe) rather than by its RTDE watchdog, which the box reports as a
            # runtime error. The daemon vented before it closed this worker's input.
            try:
                if self.control.isProgramRunning():
                    self.control.stopScript()
            except Exception:  # noqa: BLE001, S110 - the watchdog stops it anyway
                pass
        ifaces = [iface for iface in (self.control, self.io, self.receive) if iface is not None]
        threads = [threading.Thread(target=_disconnect, args=(iface,)) for iface in ifaces]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        keep_until_exit(*ifaces)


def _disconnect(iface) -> None:
    try:
        iface.disconnect()
    except Exception:  # noqa: BLE001, S110 - leaving anyway
        pass


OPS = ("digital_out", "analog_out", "move_l", "stop_l", "ensure_program")


def main(argv: list[str]) -> int:
    # Ctrl-C and a service manager's stop signal reach the whole process group; the
    # daemon still needs this process to vent, and closes its stdin when it is done
    # (or when it dies): end of input is the only way out.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    args = json.loads(argv[0])
    # ur_rtde prints to std::cout: keep fd 1 for it (sent to stderr), answer on a copy
    out = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)
    worker = Worker(args, out)
    try:
        worker.connect()
    except Exception as exc:  # noqa: BLE001 - reported to the daemon
        worker.emit({"error": f"{type(exc).__name__}: {exc}"})
        return 1
    worker.emit({"ready": True})
    period = 1.0 / float(args.get("status_hz", 50.0))
    next_status = time.monotonic()
    buffer = b""
    fd = sys.stdin.fileno()
    try:
        while True:
            ready, _, _ = select.select([fd], [], [], max(0.0, next_status - time.monotonic()))
            if ready:
                chunk = os.read(fd, 65536)
                if not chunk:
                    return 0
                buffer += chunk
                while b"\n" in buffer:
                    line, _, buffer = buffer.partition(b"\n")
                    if not line.strip():
                        continue
                    req = json.loads(line)
                    if req.get("op") == "kick":
                        worker.kick()
                    else:
                        worker.emit(worker.handle(req))
            if time.monotonic() >= next_status:
                worker.emit({"status": worker.status()})
                next_status = max(next_status + period, time.monotonic())
    finally:
        worker.close()


if __name__ == "__main__":
    exit_now(main(sys.argv[1:]))
