"""Line-oriented SCPI over a serial port: a line reader that never trusts a partial line,
queries with a wall timeout, and parsers for the replies the station relies on.

pyserial's `readline()` returns whatever arrived when its timeout expires, terminator or not;
here a line exists only once its LF has arrived, so a half reply is never taken for a value.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from typing import Any, Protocol

from drivers.errors import ConnectionLost, InstrumentTimeout, ProtocolError, ScpiError

log = logging.getLogger(__name__)

TERMINATOR = b"\n"
MAX_LINE_BYTES = 512
ERROR_QUEUE_DEPTH = 64  # stop draining after this many entries: the queue must be broken


class SerialLike(Protocol):
    """The part of pyserial's `Serial` the SCPI port uses."""

    @property
    def in_waiting(self) -> int: ...

    def read(self, size: int = 1) -> bytes: ...

    def write(self, data: bytes) -> int | None: ...

    def reset_input_buffer(self) -> None: ...

    def close(self) -> None: ...


def open_serial(path: str, *, baudrate: int = 115200, read_timeout_s: float = 0.02) -> Any:
    """Open a serial port (or pty) without touching DTR/RTS beyond what pyserial tolerates."""
    import serial  # local: byte-level tests do not need pyserial

    try:
        return serial.Serial(path, baudrate=baudrate, timeout=read_timeout_s, write_timeout=1.0)
    except (serial.SerialException, OSError) as exc:
        raise ConnectionLost(
            f"cannot open serial port {path}: {exc}; check the cable and the port name in the "
            "station configuration",
        ) from exc


class LineReader:
    """Incremental LF-terminated line splitter with a bound on line length.

    `feed` returns the complete lines (CR and LF stripped, decoded as ASCII, undecodable bytes
    replaced). Bytes beyond MAX_LINE_BYTES without an LF are dropped and counted in
    `overflow_bytes`, so garbage without terminators cannot grow memory.
    """

    def __init__(self, max_line_bytes: int = MAX_LINE_BYTES) -> None:
        self._buf = bytearray()
        self._max = max_line_bytes
        self._overflowing = False
        self.overflow_bytes = 0

    def feed(self, data: bytes) -> list[str]:
        lines: list[str] = []
        start = 0
        while True:
            end = data.find(TERMINATOR, start)
            piece = data[start:] if end < 0 else data[start:end]
            room = self._max - len(self._buf)
            if len(piece) > room:
                self.overflow_bytes += len(piece) - room
                piece = piece[:room]
                self._overflowing = True
            self._buf += piece
            if end < 0:
                return lines
            if self._overflowing:
                self._overflowing = False  # a line cut short is no reply: drop it
            else:
                lines.append(self._buf.decode("ascii", "replace").rstrip("\r"))
            self._buf.clear()
            start = end + 1

    def clear(self) -> None:
        self._buf.clear()
        self._overflowing = False

    @property
    def pending(self) -> int:
        return len(self._buf)


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


class ScpiPort:
    """Commands and queries on one serial port, one at a time (a lock serialises callers).

    Args:
        port: an open pyserial `Serial` (or anything with its read/write API).
        timeout_s: wall seconds a query waits for its reply line.
        instrument: name used in error messages.
    """

    def __init__(
        self, port: SerialLike, *, timeout_s: float = 1.0, instrument: str = "supply"
    ) -> None:
        self._port = port
        self.timeout_s = timeout_s
        self.instrument = instrument
        self._reader = LineReader()
        self._lines: list[str] = []
        self._lock = threading.Lock()

    def _write(self, text: str) -> None:
        try:
            self._port.write(text.encode("ascii") + TERMINATOR)
        except (OSError, ValueError) as exc:  # ValueError: written to a closed port
            raise ConnectionLost(
                f"cannot write to the {self.instrument}'s serial port: {exc}; check its cable",
                instrument=self.instrument,
            ) from exc
        except Exception as exc:  # serial.SerialTimeoutException and other pyserial errors
            raise ConnectionLost(
                f"writing to the {self.instrument} failed: {exc}", instrument=self.instrument
            ) from exc

    def _flush_input(self) -> None:
        """Discard a late reply to an earlier query, so it cannot answer this one."""
        try:
            self._port.reset_input_buffer()
        except (OSError, ValueError) as exc:
            raise ConnectionLost(
                f"the {self.instrument}'s serial port failed: {exc}", instrument=self.instrument
            ) from exc
        self._reader.clear()
        self._lines.clear()

    def _read_line(self, command: str) -> str:
        deadline = time.monotonic() + self.timeout_s
        while not self._lines:
            if time.monotonic() >= deadline:
                pending = self._reader.pending
                partial = f" ({pending} bytes of an unfinished line)" if pending else ""
                raise InstrumentTimeout(
                    f"the {self.instrument} did not answer {command!r} within "
                    f"{self.timeout_s:g} s{partial}: check that it is on, its serial cable and "
                    "the baud rate",
                    instrument=self.instrument,
                )
            try:
                data = self._port.read(max(1, self._port.in_waiting))
            except (OSError, ValueError) as exc:
                raise ConnectionLost(
                    f"reading from the {self.instrument} failed: {exc}; check its cable",
                    instrument=self.instrument,
                ) from exc
            except Exception as exc:  # serial.SerialException
                raise ConnectionLost(
                    f"reading from the {self.instrument} failed: {exc}", instrument=self.instrument
                ) from exc
            if data:
                self._lines.extend(self._reader.feed(data))
        return self._lines.pop(0)

    def write(self, command: str) -> None:
        """Send a setting (no reply expected)."""
        with self._lock:
            self._flush_input()
            self._write(command)

    def query(self, command: str) -> str:
        with self._lock:
            self._flush_input()
            self._write(command)
            return self._read_line(command)

    def errors(self) -> list[tuple[int, str]]:
        """Drain the error queue (SYST:ERR? until +0)."""
        found: list[tuple[int, str]] = []
        for _ in range(ERROR_QUEUE_DEPTH):
            code, text = parse_error_reply(self.query("SYST:ERR?"))
            if code == 0:
                return found
            found.append((code, text))
        raise ProtocolError(
            f"the {self.instrument}'s error queue did not empty after {ERROR_QUEUE_DEPTH} reads",
            instrument=self.instrument,
        )

    def setting(self, command: str) -> None:
        """Send a setting, then check the error queue; ScpiError names the command."""
        self.write(command)
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
        try:
            self._port.close()
        except OSError as exc:
            log.warning("closing the %s's port: %s", self.instrument, exc)
