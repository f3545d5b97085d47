"""SCPI shared by every SCPI instrument: the command layer (settings checked against the error
queue), parsers for the replies the station relies on, and the serial-port helpers the fixture
link uses.

The line transport is `drivers.visa.VisaTransport` (pyvisa + pyvisa-py); a reply exists only
once its LF has arrived, so a half reply is never taken for a value (it is a timeout).
"""

from __future__ import annotations

import logging
import re
from typing import Any, Protocol

from drivers.errors import ConnectionLost, ProtocolError, ScpiError
from drivers.fd_wait import use_poll

log = logging.getLogger(__name__)

ERROR_QUEUE_DEPTH = 64  # stop draining after this many entries: the queue must be broken


class SerialLike(Protocol):
    """The part of pyserial's `Serial` the fixture link uses."""

    @property
    def in_waiting(self) -> int: ...

    def read(self, size: int = 1) -> bytes: ...

    def write(self, data: bytes) -> int | None: ...

    def reset_input_buffer(self) -> None: ...

    def close(self) -> None: ...


def open_serial(path: str, *, baudrate: int = 115200, read_timeout_s: float = 0.02) -> Any:
    """Open a serial port (or pty) without touching DTR/RTS beyond what pyserial tolerates."""
    import serial  # local: byte-level tests do not need pyserial

    use_poll()  # pyserial waits with select(): any descriptor number (drivers/fd_wait.py)
    try:
        return serial.Serial(path, baudrate=baudrate, timeout=read_timeout_s, write_timeout=1.0)
    except (serial.SerialException, OSError) as exc:
        raise ConnectionLost(
            f"cannot open serial port {path}: {exc}; check the cable and the port name in the "
            "station configuration",
        ) from exc


_ERROR_RE = re.compile(r'\s*([-+]?\d{1,6})\s*,\s*"?(.*?)"?\s*')


def parse_error_reply(line: str) -> tuple[int, str]:
    """`-222,"Data out of range"` -> (-222, "Data out of range"); ProtocolError otherwise."""
    m = _ERROR_RE.fullmatch(line)
    if m is None:
        raise ProtocolError(f"SYST:ERR? answered {line!r}, not '<code>,\"<text>\"'")
    return int(m.group(1)), m.group(2)


def parse_float(line: str, what: str) -> float:
    try:
        value = float(line.strip())
    except ValueError:
        raise ProtocolError(f"{what} answered {line!r}, not a number") from None
    if value != value or value in (float("inf"), float("-inf")):
        raise ProtocolError(f"{what} answered {line!r}, not a finite number")
    return value


class ScpiTransport(Protocol):
    """One SCPI message line out, one reply line back (`drivers.visa.VisaTransport`)."""

    instrument: str

    def write(self, command: str) -> None: ...

    def query(self, command: str) -> str: ...

    def close(self) -> None: ...


class ScpiCommands:
    """The SCPI command layer shared by every SCPI instrument: queries, and settings checked
    against the instrument's error queue.

    Args:
        transport: the line transport (a VISA resource, or a test stand-in).
        error_query: the instrument's error-queue query (`SYST:ERR?`, `:SYST:ERR?`).
    """

    def __init__(self, transport: ScpiTransport, *, error_query: str = "SYST:ERR?") -> None:
        self.transport = transport
        self.instrument = transport.instrument
        self.error_query = error_query

    def query(self, command: str) -> str:
        return self.transport.query(command)

    def errors(self) -> list[tuple[int, str]]:
        """Drain the error queue (the error query until +0)."""
        found: list[tuple[int, str]] = []
        for _ in range(ERROR_QUEUE_DEPTH):
            code, text = parse_error_reply(self.transport.query(self.error_query))
            if code == 0:
                return found
            found.append((code, text))
        raise ProtocolError(
            f"the {self.instrument}'s error queue did not empty after {ERROR_QUEUE_DEPTH} reads",
            instrument=self.instrument,
        )

    def setting(self, command: str) -> None:
        """Send a setting, then check the error queue; ScpiError names the command."""
        self.transport.write(command)
        found = self.errors()
        if found:
            code, text = found[0]
            more = f" (and {len(found) - 1} more queued)" if len(found) > 1 else ""
            raise ScpiError(
                f"the {self.instrument} rejected {command!r}: {code} {text}{more}; check the "
                "value against the instrument's range",
                code=code,
                instrument=self.instrument,
            )

    def close(self) -> None:
        self.transport.close()
