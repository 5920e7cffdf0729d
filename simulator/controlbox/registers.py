"""RTDE general purpose registers: what clients and the control program share.

Inputs (``input_int_register_N`` ...) are written by RTDE clients and read by the
program; outputs are written by the program and read by clients. UR has 48 int (int32)
and 48 double registers each way, and 128 bit registers (0-63 as two 32-bit words,
64-127 one by one). Registers 0-23 are the "lower range" ur_rtde uses by default,
24-47 the upper range.
"""

from __future__ import annotations

import re

N_INT = 48
N_DOUBLE = 48
N_BITS = 128

_INDEXED = re.compile(r"^(input|output)_(int|double|bit)_register_(\d+)$")
_WORDS = re.compile(r"^(input|output)_bit_registers(0_to_31|32_to_63)$")


def _wrap_int32(value: int) -> int:
    value = int(value) & 0xFFFFFFFF
    return value - (1 << 32) if value & 0x80000000 else value


class Registers:
    """Both directions of every general purpose register."""

    def __init__(self) -> None:
        self.ints = {"input": [0] * N_INT, "output": [0] * N_INT}
        self.doubles = {"input": [0.0] * N_DOUBLE, "output": [0.0] * N_DOUBLE}
        self.bits = {"input": [False] * N_BITS, "output": [False] * N_BITS}

    # -- names -----------------------------------------------------------------------------
    @staticmethod
    def type_of(name: str) -> str | None:
        """RTDE type of a register variable, None if ``name`` is not one (or out of range)."""
        m = _INDEXED.match(name)
        if m:
            kind, index = m.group(2), int(m.group(3))
            if kind == "int" and index < N_INT:
                return "INT32"
            if kind == "double" and index < N_DOUBLE:
                return "DOUBLE"
            # bits 0-63 exist only as the two words
            if kind == "bit" and 64 <= index < N_BITS:
                return "BOOL"
            return None
        if _WORDS.match(name):
            return "UINT32"
        return None

    def read(self, name: str):
        m = _INDEXED.match(name)
        if m:
            direction, kind, index = m.group(1), m.group(2), int(m.group(3))
            return {"int": self.ints, "double": self.doubles, "bit": self.bits}[kind][direction][index]
        m = _WORDS.match(name)
        if m:
            bits = self.bits[m.group(1)]
            first = 0 if m.group(2) == "0_to_31" else 32
            return sum(1 << i for i in range(32) if bits[first + i])
        raise KeyError(name)

    def write(self, name: str, value) -> None:
        m = _INDEXED.match(name)
        if m:
            direction, kind, index = m.group(1), m.group(2), int(m.group(3))
            if kind == "int":
                self.ints[direction][index] = _wrap_int32(value)
            elif kind == "double":
                self.doubles[direction][index] = float(value)
            else:
                self.bits[direction][index] = bool(value)
            return
        m = _WORDS.match(name)
        if m:
            bits = self.bits[m.group(1)]
            first = 0 if m.group(2) == "0_to_31" else 32
            for i in range(32):
                bits[first + i] = bool((int(value) >> i) & 1)
            return
        raise KeyError(name)
