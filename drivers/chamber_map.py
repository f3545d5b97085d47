"""Register map of the thermal chamber controller (Modbus TCP, Watlow F4 style), stated once.

Used by the driver (`drivers.chamber`) and by its simulated twin. Holding registers, 0-based,
device id 1, 16-bit signed values; temperatures in tenths of C.
"""

from __future__ import annotations

from enum import IntEnum

DEVICE_ID = 1
TENTHS = 10.0


class Reg(IntEnum):
    PROCESS_VALUE = 100  # I16 R, tenths of C (air temperature at the control sensor)
    STATE = 200  # U16 R, see State
    SETPOINT = 300  # I16 RW, tenths of C; outside [SP_LOW, SP_HIGH] refused with exception 3
    SP_LIMIT_LOW = 602  # I16 R, tenths of C
    SP_LIMIT_HIGH = 603  # I16 R, tenths of C
    RUN = 1000  # U16 RW, 1 run (control active), 0 stop (heater/cooler off)
    RAMP_RATE = 1001  # U16 RW, tenths of C per minute; 0 = as fast as the chamber can
    MODEL = 40  # 8 registers ASCII
    SERIAL = 48  # 8 registers ASCII
    FIRMWARE = 56  # 4 registers ASCII


class State(IntEnum):
    STOPPED = 0
    RAMPING = 1
    AT_SETPOINT = 2  # process value within 0.5 C of setpoint
    FAULT = 3  # e.g. cannot reach setpoint (compressor fault)


STRING_REGS = {Reg.MODEL: 8, Reg.SERIAL: 8, Reg.FIRMWARE: 4}
WRITABLE = frozenset({Reg.SETPOINT, Reg.RUN, Reg.RAMP_RATE})
AT_SETPOINT_BAND_C = 0.5
