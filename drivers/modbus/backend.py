"""Build the Modbus backend: an async pymodbus client for the outputs, the
sampler process for the analog inputs, optionally the ur_rtde worker for the arm."""

from __future__ import annotations

import asyncio
import logging

from fluidsense.common.errors import ConfigError, DeviceProtocolError, DriverError, LinkLostError
from fluidsense.common.hardware import Hardware, RegulatedCircuit, TankCircuit
from fluidsense.common.wiring import AnalogScale, RegulatorWiring, Wiring
from fluidsense.drivers.ur.box import BoxWatchdogConfig
from pymodbus.client import AsyncModbusTcpClient
from pymodbus.exceptions import ModbusException

from ..backend import Backend
from ..base import BoxWatchdog, Regulator, ValveBank
from ..remote import (
    Connection,
    PolledCellSource,
    confirm_safe_on_connect,
    sampler_config,
)
from ..ur.watchdog import box_script, send_script
from .config import ModbusDriverConfig, RegisterMap

log = logging.getLogger(__name__)

_DOMAIN_CODE = {"current": 0, "voltage": 1}  # UR's analog domain registers
_DOMAIN_NAME = {code: name for name, code in _DOMAIN_CODE.items()}


class ModbusConnection(Connection):
    """One Modbus TCP connection, shared by the valves and the regulator."""

    def __init__(self, cfg: ModbusDriverConfig, read_only: bool = False):
        self.cfg = cfg
        self.read_only = read_only
        self.name = f"modbus {cfg.host}:{cfg.port}"
        self.client: AsyncModbusTcpClient | None = None
        self._lost: LinkLostError | None = LinkLostError(f"{self.name}: not connected")
        self._lock = asyncio.Lock()

    async def open(self) -> None:
        c = self.cfg
        self.client = AsyncModbusTcpClient(c.host, port=c.port, timeout=c.timeout_s, retries=0,
                                           reconnect_delay=0)  # reconnection is the source's business
        if not await self.client.connect():
            self.client.close()
            raise LinkLostError(f"{self.name}: cannot connect")
        self._lost = None
        try:
            await self._check_domains()
        except BaseException:
            await self.close()
            raise
        log.info("%s: connected", self.name)

    async def close(self) -> None:
        if self.client is not None:
            self.client.close()
            self.client = None
        self._lost = self._lost or LinkLostError(f"{self.name}: closed")

    def check(self) -> None:
        if self._lost is not None:
            raise self._lost

    async def _request(self, what: str, call):
        """One transaction at a time, each run to its reply even when its caller is
        cancelled (Ctrl-C, a stop, a timeout): abandoned in flight, its late reply would
        answer the next request, and pymodbus drops both. The safe state written right
        after a Ctrl-C once failed that way ('request ask for transaction_id=11 but got
        id=10')."""
        self.check()
        await self._lock.acquire()

        async def run():  # pymodbus raises 'Not connected' before its coroutine: keep it in the task
            return await call()
        transaction = asyncio.ensure_future(run())
        transaction.add_done_callback(lambda t: self._finished(what, t))
        try:
            reply = await asyncio.shield(transaction)
        except (ModbusException, OSError, asyncio.TimeoutError) as exc:
            raise (self._lost or LinkLostError(f"{self.name}: {what}: {exc}")) from exc
        if reply.isError():
            raise DriverError(f"{self.name}: {what} refused: {reply}")
        return reply

    def _finished(self, what: str, transaction: asyncio.Future) -> None:
        """Whoever waited (or not, if cancelled): the next transaction may go, and a failed
        one loses the link."""
        self._lock.release()
        exc = None if transaction.cancelled() else transaction.exception()
        if isinstance(exc, (ModbusException, OSError, asyncio.TimeoutError)) and self._lost is None:
            self._lost = LinkLostError(f"{self.name}: {what}: {exc}")
            log.error("%s", self._lost)

    async def read(self, address: int, count: int = 1) -> list[int]:
        reply = await self._request(f"read {address}+{count}", lambda: self.client.read_holding_registers(
            address, count=count, device_id=self.cfg.device_id))
        return reply.registers

    async def write(self, address: int, value: int) -> None:
        if self.read_only:
            raise DriverError(f"{self.name}: read-only connection: writing register {address} refused")
        await self._request(f"write {address}", lambda: self.client.write_register(
            address, value, device_id=self.cfg.device_id))

    async def _check_domains(self) -> None:
        """The box's analog input domains must match the sensors' outputs: a 4-20 mA
        transmitter on an input configured for volts reads nonsense."""
        regs = self.cfg.registers
        if regs.analog_input_domains is None:
            return
        for name, s in self.cfg.wiring.sensors.items():
            address = regs.analog_input_domains[s.analog_input]
            (domain,) = await self.read(address)
            if domain not in _DOMAIN_NAME:  # read as a domain, a lying box would get the wrong advice
                raise DeviceProtocolError(f"{self.name}: register {address} (analog input {s.analog_input}'s "
                                          f"domain) reads {domain}: the box can only say 0 (current) or 1 "
                                          "(voltage)", field=f"register {address}")
            if domain != _DOMAIN_CODE[s.transfer.domain]:
                raise ConfigError(f"driver.wiring.sensors.{name}: analog input {s.analog_input} of {self.cfg.host} "
                                  f"is set to {_DOMAIN_NAME[domain]}, the sensor outputs "
                                  f"{s.transfer.domain} (change the robot's I/O setup or the wiring)")


class ModbusValves(ValveBank):
    """Valves on digital outputs: through the set/clear mask registers when the map has
    them (no read-modify-write race with other masters), else read-modify-write."""

    reports_outputs = True

    def __init__(self, link: ModbusConnection, wiring: Wiring, regs: RegisterMap, safe: dict[str, bool]):
        super().__init__("modbus-valves", safe)
        self.link, self.wiring, self.regs = link, wiring.valves, regs

    async def _set(self, valve: str, open: bool, t: float) -> None:
        w = self.wiring[valve]
        bit, level = 1 << w.output, w.level(open)
        if self.regs.set_mask is not None:
            await self.link.write(self.regs.set_mask if level else self.regs.clear_mask, bit)
            return
        (bits,) = await self.link.read(self.regs.digital_outputs)
        await self.link.write(self.regs.digital_outputs, (bits | bit) if level else (bits & ~bit))

    async def _read_positions(self) -> dict[str, bool]:
        (bits,) = await self.link.read(self.regs.digital_outputs)
        return {name: bool(bits >> w.output & 1) == w.level(True) for name, w in self.wiring.items()}


class ModbusHeartbeat(BoxWatchdog):
    """Cells without an arm: the daemon increments a general purpose register that the
    box's watchdog program watches (drivers/ur/watchdog.py)."""

    def __init__(self, link: ModbusConnection, cfg: BoxWatchdogConfig):
        super().__init__("modbus-heartbeat", cfg.timeout_s)
        self.link, self.register = link, cfg.heartbeat_register
        self.beats = 0

    async def _kick(self) -> None:
        self.beats = (self.beats + 1) & 0xFFFF
        await self.link.write(self.register, self.beats)

    async def _ensure_running(self) -> None:
        """A beat before a cycle's first command, on the same link (its requests go in
        order): the program has counted silence since it was sent at connection, and the
        loop's own beats start with its first block, which can come after a cycle asked
        for at once. A command that reached the box first could meet the end of that
        silence and be vented a moment later: the likely cause of a command fault seen
        once in ``make test`` (the supply valve read back closed 1 s into the first
        charge, the tank never charged; no box log was kept to confirm it)."""
        await self._kick()


class ModbusRegulator(Regulator):
    def __init__(self, link: ModbusConnection, wiring: RegulatorWiring, regs: RegisterMap, scale: AnalogScale):
        super().__init__("modbus-regulator")
        self.link, self.wiring, self.regs, self.scale = link, wiring, regs, scale

    async def _set_setpoint(self, pressure_pa: float, t: float) -> None:
        w, ch = self.wiring, self.wiring.analog_output
        if self.regs.analog_output_domains is not None:
            await self.link.write(self.regs.analog_output_domains[ch], _DOMAIN_CODE[w.input])
        gain, offset = self.scale.raw_affine(w.input)
        raw = round((w.to_signal(pressure_pa) - offset) / gain)
        await self.link.write(self.regs.analog_outputs[ch], min(65535, max(0, raw)))


def modbus_inputs(cfg: ModbusDriverConfig, channels: tuple[str, ...]) -> list[list[float]]:
    """Per channel [register, k, c] with Pa = k * raw + c."""
    out = []
    for name in channels:
        s = cfg.wiring.sensors[name]
        gain, offset = s.transfer.affine()
        raw_gain, raw_offset = cfg.analog.raw_affine(s.transfer.domain)
        out.append([cfg.registers.analog_inputs[s.analog_input], raw_gain / gain, (raw_offset - offset) / gain])
    return out


def modbus_domains(cfg: ModbusDriverConfig, channels: tuple[str, ...]) -> list[list[int]]:
    """Per wired input of ``channels`` [analog input, domain register, code expected]; none
    for a map without domain registers (a generic I/O module)."""
    regs = cfg.registers.analog_input_domains
    if regs is None:
        return []
    inputs = sorted({cfg.wiring.sensors[name].analog_input: cfg.wiring.sensors[name].transfer.domain
                     for name in channels}.items())
    return [[ch, regs[ch], _DOMAIN_CODE[domain]] for ch, domain in inputs]


def build(cfg: ModbusDriverConfig, hw: Hardware, read_only: bool = False) -> Backend:
    """``read_only``: the Modbus connection refuses writes, nothing runs at connection (no
    safe positions written, no watchdog sent) and the arm is left out (its control
    script would take the robot over)."""
    from ..ur.backend import scene_link, worker_link  # noqa: PLC0415 - no ur_rtde import on this side
    from ..ur.devices import UrArm, WorkerKick  # noqa: PLC0415

    link = ModbusConnection(cfg, read_only)
    links: list[Connection] = [link]
    arm = watchdog = None
    if read_only:
        pass  # no arm, no watchdog
    elif cfg.arm is not None:
        worker = worker_link(cfg.host, cfg.arm, io=False, watchdog=cfg.watchdog)
        links.append(worker)
        arm = UrArm(worker, cfg.arm)
        if cfg.watchdog is not None:  # ur_rtde's script is the box's program: its RTDE watchdog
            watchdog = WorkerKick(worker, cfg.watchdog)
    elif cfg.watchdog is not None:  # the box runs fluidsense's watchdog program
        watchdog = ModbusHeartbeat(link, cfg.watchdog)
    # program: integrator: the watchdog thread is in the integrator's program; nothing is sent
    script = None if cfg.watchdog is None or read_only or cfg.watchdog.program == "integrator" else \
        box_script(cfg.wiring.valves, hw.circuit.safe_valves, cfg.watchdog, arm=cfg.arm is not None)
    poller = {"host": cfg.host, "port": cfg.port, "device_id": cfg.device_id, "timeout_s": cfg.timeout_s,
              "inputs": modbus_inputs(cfg, hw.channels), "domains": modbus_domains(cfg, hw.channels)}
    sampler = sampler_config("fluidsense.drivers.modbus.poller:ModbusAnalogPoller", poller, hw.channels, cfg.rate_hz,
                             cfg.block_size, cfg.sampler, cfg.reconnect.connect_timeout_s)
    regulated = isinstance(hw.circuit, (TankCircuit, RegulatedCircuit))
    regulator = ModbusRegulator(link, cfg.wiring.regulator, cfg.registers, cfg.analog) if regulated else None
    source = PolledCellSource("modbus", sampler, links, cfg.reconnect)
    valves = ModbusValves(link, cfg.wiring, cfg.registers, hw.circuit.safe_valves)
    if not read_only:
        source.on_connect.append(lambda: confirm_safe_on_connect(valves))
    if script is not None:
        source.on_connect.append(lambda: send_script(cfg.host, cfg.watchdog.script_port, script))
    return Backend(name="modbus", source=source, valves=valves, regulator=regulator, arm=arm,
                   scene=None if read_only else scene_link(cfg.host, cfg.sim_control_port), watchdog=watchdog)
