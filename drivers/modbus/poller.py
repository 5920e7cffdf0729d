"""Analog inputs over Modbus TCP, read in the sampler process: one request per slot
reads every wired input (a contiguous block of holding registers).

The reply is the box's word: one with more or fewer registers than were asked for is
no reply to this request (another master's, or a broken server) and nothing after it
is trusted: DeviceProtocolError naming ``registers`` (the sampler ends, the daemon
faults ``driver`` and connects again). Every 16-bit value is a possible raw count (the
map spans the whole 0-65535 range onto the input's range: common/wiring.py AnalogScale),
so no single value is impossible.

The analog input domains (UR registers 5 and 7: 0 current, 1 voltage) are read in the
same request and checked at every poll: set-up checked them against the wiring
(backend.py), and a box whose input changes domain mid-run (someone's I/O setup, another
master's write) measures another quantity than the sensor gives, which would read as
pressures (a voltage sensor on a current input reads 0 mA: the sensor's rail). A domain
other than the wiring's is a DeviceProtocolError naming the register and the domain
expected; a value other than 0 or 1 is one too."""

from __future__ import annotations

from fluidsense.common.errors import DeviceProtocolError

from ..sampler.poller import Poller


_DOMAIN_NAME = {0: "current", 1: "voltage"}  # UR's analog domain registers


class ModbusAnalogPoller(Poller):
    def __init__(self, host: str, port: int, device_id: int, inputs: list[list[float]], timeout_s: float = 0.5,
                 domains: list[list[int]] | None = None) -> None:
        """``inputs``: per channel ``[register, k, c]``: Pa = k * raw + c. ``domains``:
        per wired input ``[analog input, domain register, code expected]`` (0 current,
        1 voltage), read with the inputs and checked at every poll."""
        self.host, self.port, self.device_id, self.timeout_s = host, int(port), int(device_id), float(timeout_s)
        self.inputs = [(int(reg), float(k), float(c)) for reg, k, c in inputs]
        self.domains = [(int(ch), int(reg), int(code)) for ch, reg, code in domains or []]
        registers = [reg for reg, _, _ in self.inputs] + [reg for _, reg, _ in self.domains]
        self.first = min(registers)
        self.count = max(registers) - self.first + 1
        self._expected = [(reg - self.first, code) for _, reg, code in self.domains]
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
        for i, code in self._expected:
            if regs[i] != code:
                self._wrong_domain(regs[i], i + self.first)
        return tuple(k * regs[reg - self.first] + c for reg, k, c in self.inputs)

    def _wrong_domain(self, value: int, register: int) -> None:
        ch, _, code = next(d for d in self.domains if d[1] == register)
        expected = f"{code} ({_DOMAIN_NAME[code]}, as the wiring's sensor outputs)"
        if value not in _DOMAIN_NAME:
            raise DeviceProtocolError(f"register {register}: analog input {ch}'s domain reads {value}, which no "
                                      f"domain is (0 current, 1 voltage); expected {expected}", f"register {register}")
        raise DeviceProtocolError(f"register {register}: analog input {ch}'s domain changed to {value} "
                                  f"({_DOMAIN_NAME[value]}) mid-run; expected {expected}: its readings are not the "
                                  "sensor's (check the robot's I/O setup, and who else writes to the box)",
                                  f"register {register}")

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
