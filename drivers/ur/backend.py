"""Build the ur-rtde backend: the worker process for IO and motion, the sampler process
for the analog inputs, the simulated cell's control channel when there is one."""

from __future__ import annotations

from fluidsense.common.hardware import Hardware, RegulatedCircuit, TankCircuit
from fluidsense.common.wiring import Wiring
from fluidsense.drivers.ur.box import BoxWatchdogConfig

from ..backend import Backend
from ..remote import PolledCellSource, confirm_safe_on_connect, sampler_config
from .config import UrDriverConfig
from .devices import UrArm, UrRegulator, UrValves, WorkerKick
from .link import WorkerConnection
from .watchdog import box_script, send_script


def rtde_inputs(wiring: Wiring, channels: tuple[str, ...]) -> list[list]:
    """Per channel [analog input, k, c, domain] with Pa = k * reading + c; RTDE reads V or
    mA; the domain bounds what a reading can be (poller.py)."""
    out = []
    for name in channels:
        s = wiring.sensors[name]
        gain, offset = s.transfer.affine()
        unit = 1.0 if s.transfer.domain == "voltage" else 1e-3
        out.append([s.analog_input, unit / gain, -offset / gain, s.transfer.domain])
    return out


def worker_link(host: str, arm, io: bool, watchdog: BoxWatchdogConfig | None = None,
                control: bool = True) -> WorkerConnection:
    """``watchdog``: arm ur_rtde's RTDE watchdog so that the control script stops (and the
    box's run-state output actions vent) when the daemon stops kicking it. Without ``io``
    and ``control`` the worker only receives (status, outputs): it cannot write."""
    return WorkerConnection({"host": arm.host or host, "io": io, "control": control, "status_hz": arm.status_hz,
                       "upper_range_registers": arm.upper_range_registers,
                       "watchdog_hz": None if watchdog is None else 1.0 / watchdog.timeout_s})


def scene_link(host: str, port: int | None):
    if port is None:
        return None
    from fluidsense.drivers.simlink import RemoteScene  # noqa: PLC0415 - a simulated cell was asked for

    return RemoteScene(host, port)


def build(cfg: UrDriverConfig, hw: Hardware, read_only: bool = False) -> Backend:
    """``read_only``: the worker only receives (no IO interface: the valves cannot be
    written; no control script: the robot's own program keeps running), and nothing
    runs at connection (no safe positions written, no watchdog sent)."""
    if read_only:
        link = worker_link(cfg.host, cfg.arm, io=False, control=False)
    else:
        link = worker_link(cfg.host, cfg.arm, io=True, watchdog=cfg.watchdog)
    poller = {"host": cfg.host, "frequency": cfg.rate_hz, "inputs": rtde_inputs(cfg.wiring, hw.channels),
              "upper_range_registers": cfg.arm.upper_range_registers, "stale_s": cfg.rtde_timeout_s}
    sampler = sampler_config("fluidsense.drivers.ur.poller:RtdeAnalogPoller", poller, hw.channels, cfg.rate_hz,
                             cfg.block_size, cfg.sampler, cfg.reconnect.connect_timeout_s)
    source = PolledCellSource("ur", sampler, [link], cfg.reconnect)
    regulated = isinstance(hw.circuit, (TankCircuit, RegulatedCircuit))
    regulator = UrRegulator(link, cfg.wiring.regulator, cfg.analog) if regulated else None
    valves = UrValves(link, cfg.wiring.valves, hw.circuit.safe_valves)
    if not read_only:
        source.on_connect.append(lambda: confirm_safe_on_connect(valves))
    watchdog = None
    if cfg.watchdog is not None and not read_only:
        watchdog = WorkerKick(link, cfg.watchdog)
        script = box_script(cfg.wiring.valves, hw.circuit.safe_valves, cfg.watchdog, arm=True)
        source.on_connect.append(lambda: send_script(cfg.host, cfg.watchdog.script_port, script))
    return Backend(name="ur", source=source, valves=valves, regulator=regulator, arm=UrArm(link, cfg.arm),
                   scene=None if read_only else scene_link(cfg.host, cfg.sim_control_port), watchdog=watchdog)
