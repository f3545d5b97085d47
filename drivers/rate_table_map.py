"""Register map of the servo rate table (Modbus TCP), stated once.

Used by the driver (`drivers.rate_table`) and by its simulated twin. Holding registers,
0-based, device id 1; 32-bit values big-endian (high word first), each pair read or written in
one request. Registers 22-29 are one snapshot: read them in a single request to get encoder,
position, rate and the controller's timestamp from the same servo cycle.
"""

from __future__ import annotations

from enum import IntEnum, IntFlag

DEVICE_ID = 1
COUNTS_PER_REV = 1 << 20  # optical encoder, counts per revolution (after interpolation)


class Reg(IntEnum):
    CONTROL = 0  # U16 RW, see Control
    MODE = 1  # U16 RW, see Mode
    POS_CMD = 2  # I32 RW, millidegrees
    RATE_CMD = 4  # I32 RW, millidegrees/s
    ACCEL_LIMIT = 6  # I32 RW, millidegrees/s^2
    MOVE_TIME = 8  # I32 RW, ms; 0 = use ACCEL_LIMIT (trapezoid), >0 = smooth move of that length
    STATUS = 20  # U16 R, see Status
    FAULT_CODE = 21  # U16 R, see Fault
    ENCODER_COUNTS = 22  # U32 R, raw, wraps
    POS_FB = 24  # I32 R, millidegrees, continuous (not wrapped to one turn) since zeroing
    RATE_FB = 26  # I32 R, millidegrees/s
    SNAPSHOT_TIME = 28  # U32 R, controller clock, microseconds, wraps every 2^32 us
    HEARTBEAT = 30  # U16 R, increments every servo cycle batch; stops when the controller hangs
    MODEL = 40  # 8 registers, ASCII, 2 chars per register, high byte first, NUL padded
    SERIAL = 48  # 8 registers, ASCII
    FIRMWARE = 56  # 4 registers, ASCII


SNAPSHOT_START = Reg.ENCODER_COUNTS
SNAPSHOT_COUNT = 8  # 22..29
STRING_REGS = {Reg.MODEL: 8, Reg.SERIAL: 8, Reg.FIRMWARE: 4}
WRITABLE = frozenset(range(0, 10))  # client writes outside 0..9 are refused (exception 2)


class Control(IntFlag):
    ENABLE = 1 << 0
    HALT = 1 << 1
    FAULT_RESET = 1 << 2  # edge-triggered: write 1, the controller clears it
    ZERO_ENCODER = 1 << 3  # edge-triggered


class Mode(IntEnum):
    IDLE = 0
    POSITION = 1
    RATE = 2


class Status(IntFlag):
    READY = 1 << 0
    ENABLED = 1 << 1
    FAULT = 1 << 2
    IN_POSITION = 1 << 3
    AT_RATE = 1 << 4
    MOVING = 1 << 5
    INTERLOCK_OPEN = 1 << 7


class Fault(IntEnum):
    NONE = 0
    OVERSPEED = 1
    FOLLOWING_ERROR = 2
    ENCODER_LOSS = 3
    ESTOP = 4


FAULT_TEXT = {
    Fault.NONE: "no fault",
    Fault.OVERSPEED: "overspeed: the table exceeded its rate limit",
    Fault.FOLLOWING_ERROR: "following error: the table could not follow its command "
    "(load, friction or a blocked axis)",
    Fault.ENCODER_LOSS: "encoder signal lost: check the encoder cable and read head",
    Fault.ESTOP: "emergency stop pressed: release it, then reset the fault",
}

MAX_RATE_DPS = 1000.0  # controller's overspeed limit
AT_RATE_TOLERANCE_DPS = 0.05  # AT_RATE set when |rate error| below this for the settle time
IN_POSITION_TOLERANCE_DEG = 0.001  # IN_POSITION set when |position error| below this and at rest
