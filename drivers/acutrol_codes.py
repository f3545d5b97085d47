"""The ACUTROL command dialect the station speaks, stated once (driver and twin).

ASCII over TCP. The station sends one line per request, ended by CR LF; several commands may
share a line, separated by `;` (a header without a leading `:` continues the previous
subsystem, as in `:read:pos? 1;rate? 1`). The controller answers every line with one line
ended by CR LF: the query results joined by `;`, or `OK` when the line held no query, or
`ERR <code>,"<text>"` for the first command it refused (commands before it took effect).
Numbers are decimal degrees, deg/s, deg/s^2 and seconds; `<axis>` is the axis number.

| command | meaning |
| --- | --- |
| `*IDN?` | `manufacturer,model,serial,firmware` |
| `:interlock:close <axis>` | close the axis interlock: power the drive (enable) |
| `:interlock:open <axis>` | open it: controlled stop, drive off (disable) |
| `:interlock:reset <axis>` | clear latched faults (refused while the e-stop is pressed) |
| `:interlock? <axis>` | `Closed`, `Open` or `Fault` |
| `:mode:rate <axis>`, `:mode:position <axis>` | operating mode |
| `:mode? <axis>` | `Rate`, `Position` or `Off` |
| `:demand:rate <axis>,<dps>` | rate demand (rate mode) |
| `:demand:position <axis>,<deg>` | position demand (position mode) |
| `:limit:acc rate|pos,<axis>,<dps2>` | acceleration limit of a mode (and `? rate|pos,<axis>`) |
| `:limit:rate rate|pos,<axis>,<dps>` | rate limit of a mode (and `? rate|pos,<axis>`) |
| `:limit:absolute? <axis>` | `rate,acc,jerk,pos_lo,pos_hi,vtrip`, the table's hard limits |
| `:read:pos? <axis>`, `:read:rate? <axis>`, `:read:acc? <axis>` | feedback |
| `:status? <axis>` | status word, `StatusBit` |
| `:fault? <axis>` | latched fault code, `FAULT_TEXT` (0: none) |
| `:system:time?` | controller clock, s, microsecond resolution |

Position is the axis' accumulated angle since the controller's zero (not wrapped to a turn).
"""

from __future__ import annotations

from enum import IntEnum, IntFlag

MANUFACTURER = "Acutronic"


class StatusBit(IntFlag):
    READY = 1 << 0  # no fault, safety loop closed, e-stop released
    CLOSED = 1 << 1  # axis interlock closed: the drive is powered (enabled)
    FAULT = 1 << 2  # a fault is latched (see :fault?)
    IN_POSITION = 1 << 3
    AT_RATE = 1 << 4
    MOVING = 1 << 5
    ESTOP = 1 << 6  # emergency stop pressed
    SAFETY_OPEN = 1 << 7  # the table's safety interlock (door, guard) is open


class Err(IntEnum):
    """Codes of `ERR <code>,"<text>"` replies."""

    DATA_TYPE = -104  # a parameter is not a number
    MISSING_PARAMETER = -109
    UNDEFINED_HEADER = -113  # unknown command
    SETTINGS_CONFLICT = -221  # e.g. a demand for a mode the axis is not in
    OUT_OF_RANGE = -222  # a value beyond a limit
    SAFETY_OPEN = 201  # the axis cannot be closed: the safety interlock is open
    FAULT_LATCHED = 202  # the axis cannot be closed: reset the fault first
    ESTOP = 203  # the e-stop is pressed


class Fault(IntEnum):
    NONE = 0
    OVERSPEED = 1
    FOLLOWING_ERROR = 2
    TRANSDUCER = 3
    ESTOP = 4


FAULT_TEXT = {
    Fault.NONE: "no fault",
    Fault.OVERSPEED: "rate trip: the axis exceeded its rate trip limit",
    Fault.FOLLOWING_ERROR: "position error trip: the axis could not follow its demand "
    "(load, friction or a blocked axis)",
    Fault.TRANSDUCER: "position transducer fault: check the encoder cable and read head",
    Fault.ESTOP: "emergency stop pressed: release it, then reset the interlock",
}


def fault_text(code: int) -> str:
    try:
        return FAULT_TEXT[Fault(code)]
    except ValueError:
        return f"unknown fault code {code}: see the ACUTROL manual, then reset the interlock"
