"""Typed instrument exceptions.

Every driver raises one of these, never a bare socket or serial error, and every message
says what happened and what the operator or engineer can do about it. The station maps them
to an ERROR verdict with the message as the reason.
"""

from __future__ import annotations


class InstrumentError(Exception):
    """Base class: something went wrong talking to or inside an instrument."""

    instrument: str = "instrument"

    def __init__(self, message: str, *, instrument: str | None = None) -> None:
        super().__init__(message)
        if instrument is not None:
            self.instrument = instrument


class ConnectionLost(InstrumentError):
    """The link to the instrument is down (socket closed, port gone, no answer at all)."""


class WrongInstrument(ConnectionLost):
    """After a reconnect by address, the address leads to another device than the one first
    opened (a USB serial adapter re-enumerated, a port number given to another device):
    nothing is commanded there, and retrying cannot help."""


class InstrumentTimeout(InstrumentError):
    """The instrument answered too late, or a wait (at rate, in position, setpoint) ran out."""


class ProtocolError(InstrumentError):
    """The instrument answered something that does not fit its protocol."""


class TableFault(InstrumentError):
    """The rate table reports a fault (following error, overspeed, encoder loss, e-stop)."""

    def __init__(self, message: str, *, fault_code: int, instrument: str | None = None) -> None:
        super().__init__(message, instrument=instrument)
        self.fault_code = fault_code


class InterlockOpen(TableFault):
    """The table's safety interlock (door, guard) is open; motion is refused."""


class ChamberSetpointNotReached(InstrumentTimeout):
    """The chamber did not reach its setpoint within the allowed time."""


class SetpointOutOfRange(InstrumentError):
    """A setpoint outside the instrument's configured limits was refused."""


class ScpiError(InstrumentError):
    """The supply's error queue reported an error after a setting."""

    def __init__(self, message: str, *, code: int, instrument: str | None = None) -> None:
        super().__init__(message, instrument=instrument)
        self.code = code


class SupplyCurrentLimit(InstrumentError):
    """The supply went into constant-current mode: the part draws too much (short?)."""


class PartAbsent(InstrumentError):
    """No part answers in the fixture socket."""


class PartSilent(InstrumentTimeout):
    """The part was streaming and stopped sending frames."""


class StreamCorrupted(InstrumentError):
    """More frames were lost or corrupted than the procedure allows."""


class ChamberFault(InstrumentError):
    """The chamber controller reports its FAULT state (compressor, heater, sensor)."""


class ControllerHung(InstrumentError):
    """An instrument answers but its controller has stopped (its heartbeat does not advance)."""


class ChamberAlarm(ChamberSetpointNotReached, ChamberFault):
    """The chamber controller reports an alarm (deviation, heater, refrigeration, limit):
    it will not hold its setpoint until the alarm is cleared at the chamber."""


class ChamberRefused(InstrumentError):
    """The chamber controller understood a command but refused it in its present state
    (panel protection on, controller not ready): the message says what to change there."""
