"""Analog inputs over Modbus TCP, read in the sampler process: one request per slot
reads every wired input (a contiguous block of holding registers).

The reply is the box's word: one with more or fewer registers than were asked for is
no reply to this request (another master's, or a broken server) and nothing after it
is trusted: DeviceProtocolError naming ``registers`` (the sampler ends, the daemon
faults ``driver`` and connects again). Every 16-bit value is a possible raw count (the
map spans the whole 0-65535 range onto the input's range: common/wiring.py AnalogScale),
so no single value is impossible."""

from __future__ import annotations

from fluidsense.common.errors import DeviceProtocolError

from ..sampler.poller import Poller


class ModbusAnalogPoller(Poller):
    def __init__(self, host: str, port: int, device_id: int, inputs: list[list[float]], timeout_s: float = 0.5) -> None:
        """``inputs``: per channel ``[register, k, c]``: Pa = k * raw + c."""
        self.host, self.port, self.device_id, self.timeout_s = host, int(port), int(device_id), float(timeout_s)
        self.inputs = [(int(reg), float(k), float(c)) for reg, k, c in inputs]
        self.first = min(reg for reg, _, _ in self.inputs)
        self.count = max(reg for reg, _, _ in self.inputs) - self.first + 1
        self.client = None

    def open(self) -> None:
        from pymodbus.client import ModbusTcpClient  # noqa: PLC0415 - only in the sampler process

        # no retries: a slot that fails is counted as failed, never retried late
        self.client = ModbusTcpClient(self.host, port=self.port, timeout=self.timeout_s, retries=0)
        if not self.client.connect():
            raise ConnectionRefusedError(f"Modbus {self.host}:{self.port}: cannot connect")

    def read(self) -> tuple[float, ...]:
        reply = self.client.read_holding_registers(self.first, count=self.count, device_id=self.device_id)
        if reply.isError():
            raise ConnectionError(f"Modbus read of registers {self.first}+{self.count}: {reply}")
        regs = reply.registers
        if len(regs) != self.count:
            raise DeviceProtocolError(f"registers: {len(regs)} registers in the reply to a read of {self.count} "
                                      f"from {self.first}", "registers")
        return tuple(k * regs[reg - self.first] + c for reg, k, c in self.inputs)

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
