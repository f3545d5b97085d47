"""A CR LF terminated ASCII command/reply link over TCP or a serial port, with typed errors.

The address is `host:port` for TCP (a plain socket, `TcpLinePort`) or a serial device path such
as `/dev/ttyUSB0` (opened with pyserial; any pyserial URL, `rfc2217://...`, is passed through).
One reply line per command. A refused connection, a closed socket or a vanished port becomes
`ConnectionLost`; no complete reply within `timeout_s` wall seconds `InstrumentTimeout`. After
either the port is closed and the next command reopens it, so a late reply can never be taken
for the answer to the next command.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import threading
import time
from collections.abc import Callable
from typing import Protocol

import serial

from common.address import parse_host_port
from drivers.errors import ConnectionLost, InstrumentTimeout, ProtocolError
from drivers.fd_wait import use_poll

log = logging.getLogger(__name__)

EOL = b"\r\n"
class LinePort(Protocol):
    """The part of pyserial's API the link uses (a test fake provides it too)."""

    def write(self, data: bytes) -> int | None: ...

    def readline(self) -> bytes: ...

    def reset_input_buffer(self) -> None: ...

    def close(self) -> None: ...


class TcpLinePort:
    """A TCP connection with the `LinePort` API: buffered reads, `timeout_s` per line."""

    def __init__(self, host: str, port: int, timeout_s: float) -> None:
        self._timeout_s = timeout_s
        self._buf = bytearray()
        self._sock = socket.create_connection((host, port), timeout=timeout_s)
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def write(self, data: bytes) -> int:
        self._sock.settimeout(self._timeout_s)
        self._sock.sendall(data)
        return len(data)

    def _recv(self) -> None:
        chunk = self._sock.recv(4096)
        if not chunk:
            raise ConnectionResetError("the instrument closed the connection")
        self._buf += chunk

    def readline(self) -> bytes:
        """Up to and including the next LF; what arrived so far when `timeout_s` runs out."""
        deadline = time.monotonic() + self._timeout_s
        while b"\n" not in self._buf:
            remaining_s = deadline - time.monotonic()
            if remaining_s <= 0:
                break
            self._sock.settimeout(remaining_s)
            try:
                self._recv()
            except TimeoutError:
                break
        end = self._buf.find(b"\n") + 1 or len(self._buf)
        line = bytes(self._buf[:end])
        del self._buf[:end]
        return line

    def reset_input_buffer(self) -> None:
        """Drop anything unread (a late reply); a closed connection shows here already."""
        self._buf.clear()
        self._sock.setblocking(False)
        try:
            while True:
                self._recv()
                self._buf.clear()
        except BlockingIOError:
            pass
        finally:
            self._sock.settimeout(self._timeout_s)

    def close(self) -> None:
        self._sock.close()


def open_port(address: str, *, baudrate: int, timeout_s: float) -> LinePort:
    """Open `address` (host:port, a device path or a pyserial URL); ConnectionLost if not."""
    tcp = parse_host_port(address)
    use_poll()  # pyserial waits with select(): any descriptor number (drivers/fd_wait.py)
    try:
        if tcp is not None:
            return TcpLinePort(tcp[0], tcp[1], timeout_s)
        port: LinePort = serial.serial_for_url(
            address, baudrate=baudrate, timeout=timeout_s, write_timeout=timeout_s
        )
    except (serial.SerialException, OSError, ValueError) as exc:
        raise ConnectionLost(
            f"cannot open {address}: {exc}: check that the instrument is powered, its cable "
            "is in and the address in the station configuration is right",
        ) from None
    return port


class LineLink:
    """One command, one CR LF terminated reply line, under a lock.

    Args:
        opener: opens the port (called again after a lost connection or a timeout).
        instrument: the instrument's name in messages.
        where: the address, in messages.
        timeout_s: wall seconds a reply may take (the port's own read timeout must match).
    """

    def __init__(
        self,
        opener: Callable[[], LinePort],
        *,
        instrument: str,
        where: str,
        timeout_s: float,
    ) -> None:
        self._opener = opener
        self.instrument = instrument
        self.where = where
        self.timeout_s = timeout_s
        self._port: LinePort | None = None
        self._lock = threading.Lock()

    def connect(self) -> None:
        with self._lock:
            self._ensure_open()

    def _ensure_open(self) -> LinePort:
        if self._port is None:
            try:
                self._port = self._opener()
            except ConnectionLost as exc:
                exc.instrument = self.instrument
                raise
        return self._port

    def _drop(self) -> None:
        if self._port is not None:
            with contextlib.suppress(serial.SerialException, OSError):
                self._port.close()
            self._port = None

    def query(self, command: str) -> str:
        """Send `command` + CR LF and return the reply line without its terminator."""
        data = command.encode("ascii") + EOL
        with self._lock:
            port = self._ensure_open()
            try:
                port.reset_input_buffer()
                port.write(data)
                raw = port.readline()
            except (serial.SerialException, OSError) as exc:
                self._drop()
                raise ConnectionLost(
                    f"the connection to the {self.instrument} at {self.where} dropped during "
                    f"{command!r}: check the cable and the controller's power, then retry "
                    f"({exc})",
                    instrument=self.instrument,
                ) from None
            if not raw.endswith(EOL):
                self._drop()
                got = f" (only {raw!r} arrived)" if raw else ""
                raise InstrumentTimeout(
                    f"the {self.instrument} at {self.where} did not answer {command!r} within "
                    f"{self.timeout_s:g} s{got}: check it is on and in remote mode; the "
                    "station reconnects on the next command",
                    instrument=self.instrument,
                )
        try:
            return raw[: -len(EOL)].decode("ascii")
        except UnicodeDecodeError:
            raise ProtocolError(
                f"the {self.instrument} at {self.where} answered {command!r} with non-ASCII "
                f"bytes {raw!r}: check the baud rate and the address",
                instrument=self.instrument,
            ) from None

    def reopen(self, timeout_s: float | None = None) -> None:
        """Close the port and open it again, with a new reply timeout (wall s) if given (the
        opener must open at `self.timeout_s` for it to take effect)."""
        with self._lock:
            self._drop()
            if timeout_s is not None:
                self.timeout_s = timeout_s
            self._ensure_open()

    def close(self) -> None:
        with self._lock:
            self._drop()
