"""Watlow F4T Modbus register codec (pure functions, no I/O).

Register map of control loop 1 (loop n: + (n − 1) × 160). Seen in the Modbus tables of Watlow's F4T Setup and
Operations User's Guide (Chapter 6, relative addresses): part number 16–30, display units 1328 (15 = °C,
30 = °F), alarm blocks 100 registers apart, loop registers 160 apart, IEEE floats in two registers. Taken
from Espec North America's ChamberConnectLibrary (``watlowf4t.py``, which drives real F4Ts): process value
2820, set point 2782, range low/high 2774/2776, control mode 2730 (10 = auto, 54 = manual, 62 = off), alarm
*n* state 1356 + (n − 1) × 100 (inactive: 12 clear, 61 none, 88 startup), and the float word order, **low
word first** (``struct.pack("HH", …)`` on a little-endian host). The value the virtual F4T reports for an
*active* alarm (37, "high") is an assumption.
"""

from __future__ import annotations

import math
import struct

from drivers.errors import ReplyError

HARDWARE_ID = 0
PART_NUMBER = 16
PART_NUMBER_LENGTH = 15
DISPLAY_UNITS = 1328
ALARM1_STATE = 1356
ALARM_STRIDE = 100
CONTROL_MODE = 2730
RANGE_LOW = 2774
RANGE_HIGH = 2776
SET_POINT = 2782
PROCESS_VALUE = 2820
LOOP_STRIDE = 160

MODE_AUTO, MODE_MANUAL, MODE_OFF = 10, 54, 62
UNITS_C, UNITS_F = 15, 30
ALARM_INACTIVE = frozenset({12, 61, 88})
ALARM_ACTIVE_SIM = 37


def loop_register(base: int, loop: int) -> int:
    """Address of a loop-1 register ``base`` for control loop ``loop`` (1–4)."""
    if not 1 <= loop <= 4:
        raise ValueError(f"loop must be 1..4, got {loop}")
    return base + (loop - 1) * LOOP_STRIDE


def encode_float(value: float) -> list[int]:
    """IEEE-754 float32 as two registers, low word first: 25.0 → ``[0x0000, 0x41C8]``."""
    lo, hi = struct.unpack("<HH", struct.pack("<f", value))
    return [lo, hi]


def decode_float(registers: list[int], *, instrument: str, what: str) -> float:
    """Two registers (low word first) → float; ReplyError on a wrong count or a non-finite value."""
    if len(registers) != 2 or not all(0 <= r <= 0xFFFF for r in registers):
        raise ReplyError(instrument, f"{what}: expected two 16-bit registers", reply=repr(registers))
    value = struct.unpack("<f", struct.pack("<HH", *registers))[0]
    if not math.isfinite(value):
        raise ReplyError(instrument, f"{what}: not a finite number", reply=repr(registers))
    return value


def encode_string(text: str, length: int) -> list[int]:
    """One character per register, zero padded."""
    codes = [ord(c) for c in text[:length]]
    return codes + [0] * (length - len(codes))


def decode_string(registers: list[int]) -> str:
    out = []
    for r in registers:
        if r == 0:
            break
        out.append(chr(r) if 32 <= r < 127 else "?")
    return "".join(out)


def f_to_c(T_F: float) -> float:
    return (T_F - 32.0) / 1.8


def c_to_f(T_C: float) -> float:
    return T_C * 1.8 + 32.0
