"""Modbus TCP map of a Watlow F4T controller (loop 1..4), as ESPEC's ChamberConnectLibrary
documents it, stated once for the driver (`drivers.watlow_f4t`) and its twin.

Holding registers, 0-based addresses. Floats are IEEE-754 32-bit in two registers, low word
first (the F4T's default "word order: low-high"). Enumerated values are Watlow's parameter
codes (62 off, 10 auto, ...). A loop's registers are 160 apart (loop N: base + 160 (N - 1)).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from enum import IntEnum

DEVICE_ID = 1
LOOP_STRIDE = 160
ALARM_STRIDE = 100
PART_NUMBER_REGS = 15  # one ASCII character per register (low byte)


class Reg(IntEnum):
    PART_NUMBER = 16  # 15 registers, one character each, e.g. "F4T1R2AA2AAAAAA"
    CONTROL_MODE = 2730  # U16 RW, loop 1 user control mode: AUTO, MANUAL or OFF
    RANGE_LOW = 2774  # float RW, loop 1 setpoint range low
    RANGE_HIGH = 2776  # float RW, loop 1 setpoint range high
    SETPOINT = 2782  # float RW, loop 1 closed-loop setpoint
    WORKING_SETPOINT = 2810  # float R, loop 1 setpoint in use now
    ACTUAL_MODE = 2814  # U16 R, loop 1 control mode in effect
    PROCESS_VALUE = 2820  # float R, loop 1 process value (chamber air)
    ALARM_STATE = 1356  # U16 R, alarm 1 state; alarm N at + 100 (N - 1)
    UNITS = 6730  # U16 R, temperature display units: C or F (Modbus TCP address)
    PROFILE_ACTION = 16566  # U16 W, request to a running profile: TERMINATE, PAUSE
    PROFILE_STATE = 16568  # U16 R, profile state: RUNNING, PAUSED or another idle code


class Code(IntEnum):
    """Watlow parameter codes used here."""

    AUTO = 10
    BLOCKED = 12
    CELSIUS = 15
    ERROR = 28
    FAHRENHEIT = 30
    HIGH = 37
    LOW = 53
    MANUAL = 54
    NONE = 61
    OFF = 62
    STARTUP = 88
    PAUSE = 146
    TERMINATE = 148
    RUNNING = 149


ALARM_INACTIVE = frozenset({Code.STARTUP, Code.NONE, Code.BLOCKED})
ALARM_TEXT: dict[int, str] = {
    Code.HIGH: "a high alarm",
    Code.LOW: "a low alarm",
    Code.ERROR: "an alarm error",
}
PROFILE_ACTIVE = frozenset({Code.RUNNING, Code.PAUSE})


def loop_reg(reg: Reg, loop: int) -> int:
    """The address of a loop register for loop `loop` (1..4)."""
    return int(reg) + LOOP_STRIDE * (loop - 1)


def alarm_reg(alarm: int) -> int:
    return int(Reg.ALARM_STATE) + ALARM_STRIDE * (alarm - 1)


def float_to_regs(value: float) -> list[int]:
    """An IEEE-754 float32 as two registers, low word first."""
    low, high = struct.unpack("<HH", struct.pack("<f", value))
    return [low, high]


def regs_to_float(regs: Sequence[int]) -> float:
    """Two registers, low word first, as the float32 they hold (rounded to 1e-3, which is
    well inside float32's resolution at chamber temperatures and hides 85.1 -> 85.0999985)."""
    value = struct.unpack("<f", struct.pack("<HH", regs[0] & 0xFFFF, regs[1] & 0xFFFF))[0]
    return round(float(value), 3)


def regs_to_text(regs: Sequence[int]) -> str:
    """One character per register (the F4T's part-number form), NULs dropped."""
    return "".join(chr(r & 0xFF) for r in regs if r & 0xFF).strip()


def f_to_c(temp_f: float) -> float:
    return (temp_f - 32.0) * 5.0 / 9.0


def c_to_f(temp_c: float) -> float:
    return temp_c * 9.0 / 5.0 + 32.0
