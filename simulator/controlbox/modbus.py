"""Modbus TCP server with the UR control box's register map (pymodbus 3 simulator API).

Registers are unsigned 16-bit; signed values (robot mode -1, negative TCP coordinates)
wrap two's-complement. Holding and input register reads (function codes 3 and 4) see the
same map, and any unit id is answered. Every request first refreshes the registers from
the model; the inputs (0, 4, 6, 30) come from the box's I/O image, which changes at most
once per control cycle (500 Hz e-Series, 125 Hz CB3), so a faster poll reads repeats, as on
a real box. Writes go to the model through the box, so other clients see them at once.

========  ===  =========================================================================
register  r/w  meaning
========  ===  =========================================================================
0         r    digital inputs: bits 0-7 standard, 8-9 tool
1         rw   digital outputs: bits 0-7 standard, 8-9 tool
2         w    set mask: writing sets those output bits
3         w    clear mask: writing clears those output bits
4, 6      r    analog input 0, 1: raw 0-65535 over the domain's range
5, 7      rw   analog input 0, 1 domain: 0 current, 1 voltage
16, 18    rw   analog output 0, 1: raw 0-65535
17, 19    rw   analog output 0, 1 domain
30        r    configurable inputs, bits 0-7
31        rw   configurable outputs, bits 0-7 (32 set mask, 33 clear mask)
128-255   rw   general purpose
258       r    robot mode
261       r    protective stop (1 when stopped)
262       r    emergency stop (1 when stopped)
400-402   r    TCP x, y, z in 0.1 mm (base frame)
403-405   r    TCP rx, ry, rz in mrad
========  ===  =========================================================================

Other addresses in 0-33 and 256-271 read 0 and refuse writes (tool analog I/O, tool
voltage, euromap and the other robot state registers are not emulated).
"""

from __future__ import annotations

import logging

from fluidsense.simulator.controlbox.box import ControlBox
from fluidsense.simulator.controlbox.model import AnalogDomain, AnalogSignal
from pymodbus.constants import ExcCodes
from pymodbus.pdu import ModbusPDU
from pymodbus.pdu.register_message import (
    ReadHoldingRegistersRequest,
    ReadHoldingRegistersResponse,
    ReadInputRegistersRequest,
    ReadInputRegistersResponse,
)
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

log = logging.getLogger(__name__)

RAW_MAX = 0xFFFF
ANALOG_INPUTS = (4, 6)
_WRITABLE = [(1, 3), (5, 1), (7, 1), (16, 4), (31, 3), (128, 128)]  # (first address, count)
_READ_ONLY = [(0, 1), (4, 1), (6, 1), (8, 8), (20, 10), (30, 1), (256, 16), (400, 6)]


def _u16(value: int) -> int:
    return int(value) & 0xFFFF


def _s16_raw(value: float, scale: float) -> int:
    return _u16(round(value * scale))


def standard_to_register(bits: int) -> int:
    """Model bit field (0-7 standard, 16-17 tool) -> register 0/1 layout (0-7, 8-9)."""
    return (bits & 0xFF) | (((bits >> 16) & 0b11) << 8)


def register_to_standard(value: int) -> int:
    """Register 0/1 layout -> model bit field."""
    return (value & 0xFF) | (((value >> 8) & 0b11) << 16)


_STANDARD_MASK = register_to_standard(0x3FF)
_CONFIGURABLE_MASK = 0xFF << 8


class UrModbus:
    """The register map over a ControlBox."""

    def __init__(self, box: ControlBox):
        self.box = box

    def device(self) -> SimDevice:
        blocks = [SimData(a, count=n, datatype=DataType.REGISTERS) for a, n in _WRITABLE]
        blocks += [SimData(a, count=n, datatype=DataType.REGISTERS, readonly=True) for a, n in _READ_ONLY]
        # id 0: answer every unit id, as the control box does
        return SimDevice(id=0, simdata=blocks, action=self.action)

    async def action(self, function_code: int, start_address: int, address: int, count: int,
                     registers: list[int], set_values: list[int] | list[bool] | None) -> ExcCodes | None:
        try:
            if set_values is not None:
                self.write(address, [int(v) for v in set_values])
            self.refresh(registers, start_address, address, count)
        except ValueError as exc:
            log.warning("modbus write at %d refused: %s", address, exc)
            return ExcCodes.ILLEGAL_VALUE
        return None

    # -- model -> registers ---------------------------------------------------------------------
    def refresh(self, registers: list[int], start: int, first: int = 0, count: int = 1 << 16) -> None:
        """The request's registers ``first .. first + count - 1`` from the model (a poll
        reads a few of them, hundreds of times a second)."""
        box = self.box
        box.sync()
        m = box.model
        end = first + count

        def put(address: int, value: int) -> None:
            if first <= address < end:
                registers[address - start] = _u16(value)

        # inputs from the I/O image (refreshed at the control rate), their domains as set
        put(0, standard_to_register(box.image_digital_inputs))
        put(1, standard_to_register(m.digital_outputs))
        put(30, (box.image_digital_inputs >> 8) & 0xFF)
        put(31, (m.digital_outputs >> 8) & 0xFF)
        for ch, base in ((0, 4), (1, 6)):
            put(base, self.to_raw(box.image_analog_inputs[ch]))
            put(base + 1, int(m.analog_input(ch).domain))
        for ch, base in ((0, 16), (1, 18)):
            sig = m.analog_output(ch)
            put(base, self.to_raw(sig))
            put(base + 1, int(sig.domain))
        for i in range(max(first, 128) - 128, min(end, 256) - 128):
            put(128 + i, m.general_purpose(i))
        put(258, int(m.robot_mode))
        put(261, int(m.protective_stop))
        put(262, int(m.emergency_stop))
        pose = m.tcp_pose
        for i in range(3):
            put(400 + i, _s16_raw(pose[i], 1e4))  # 0.1 mm
            put(403 + i, _s16_raw(pose[3 + i], 1e3))  # mrad

    # -- registers -> model -------------------------------------------------------------------------
    def write(self, address: int, values: list[int]) -> None:
        """Apply a write of ``values`` starting at ``address`` (already checked writable)."""
        writes = dict(zip(range(address, address + len(values)), values))
        for reg in (5, 7, 17, 19):
            if reg in writes:
                _domain(writes[reg])  # refuse the whole write before any of it acts
        box, m = self.box, self.box.model
        for reg, value in writes.items():
            if reg == 1:
                box.set_digital_outputs(_STANDARD_MASK, register_to_standard(value), "modbus")
            elif reg == 2:
                mask = register_to_standard(value)
                box.set_digital_outputs(mask, mask, "modbus")
            elif reg == 3:
                box.set_digital_outputs(register_to_standard(value), 0, "modbus")
            elif reg == 31:
                box.set_digital_outputs(_CONFIGURABLE_MASK, (value & 0xFF) << 8, "modbus")
            elif reg == 32:
                box.set_digital_outputs((value & 0xFF) << 8, (value & 0xFF) << 8, "modbus")
            elif reg == 33:
                box.set_digital_outputs((value & 0xFF) << 8, 0, "modbus")
            elif reg in (5, 7):
                m.set_analog_input((reg - 5) // 2, domain=_domain(value))
            elif 128 <= reg <= 255:
                m.set_general_purpose(reg - 128, value)
        # analog outputs: the domain first, so a raw value written with it uses it
        for ch, base in ((0, 16), (1, 18)):
            if base in writes or base + 1 in writes:
                old = m.analog_output(ch)
                domain = _domain(writes[base + 1]) if base + 1 in writes else old.domain
                raw = writes[base] if base in writes else self.to_raw(old)
                box.set_analog_output(ch, self.from_raw(raw, domain), domain)

    # -- scale --------------------------------------------------------------------------------------
    def to_raw(self, signal: AnalogSignal) -> int:
        lo, hi = self.box.config.analog.span(signal.domain)
        ratio = (signal.value - lo) / (hi - lo)
        return round(min(1.0, max(0.0, ratio)) * RAW_MAX)

    def from_raw(self, raw: int, domain: AnalogDomain) -> float:
        lo, hi = self.box.config.analog.span(domain)
        return lo + (raw / RAW_MAX) * (hi - lo)


def _domain(value: int) -> AnalogDomain:
    if value not in (0, 1):
        raise ValueError(f"analog domain must be 0 (current) or 1 (voltage), got {value}")
    return AnalogDomain(value)


class ModbusServer:
    def __init__(self, box: ControlBox, host: str, port: int):
        self.map = UrModbus(box)
        self.host, self.port = host, port
        self._server: ModbusTcpServer | None = None
        self._reads: dict[int, int] = {}  # transaction id -> address of a read in progress

    async def start(self) -> None:
        self._server = ModbusTcpServer(self.map.device(), address=(self.host, self.port), trace_pdu=self._lie)
        await self._server.serve_forever(background=True)

    def _lie(self, sending: bool, pdu: ModbusPDU) -> ModbusPDU:
        """A reply to a read of the analog inputs as the box's lie (sim control ``lie``) has
        it. The reply does not say what was read: its request's address is kept by
        transaction id (each client numbers its own; two clients' equal ids at the same
        moment could mix, which a test's lie can live with)."""
        if not sending:
            if isinstance(pdu, ReadHoldingRegistersRequest | ReadInputRegistersRequest):
                self._reads[pdu.transaction_id] = pdu.address
        elif isinstance(pdu, ReadHoldingRegistersResponse | ReadInputRegistersResponse):
            address = self._reads.pop(pdu.transaction_id, None)
            if address in ANALOG_INPUTS:
                pdu.registers = self.map.box.lies.modbus(self.map.box.model.t, pdu.registers, address)
        return pdu

    async def close(self) -> None:
        if self._server is not None:
            await self._server.shutdown()
