"""Analog inputs over Modbus TCP, read in the sampler process: one request per slot
reads every wired input (a contiguous block of holding registers)."""

from __future__ import annotations

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
        return tuple(k * regs[reg - self.first] + c for reg, k, c in self.inputs)

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
