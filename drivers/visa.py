"""SCPI instruments over any VISA resource: pyvisa with the pure-Python pyvisa-py backend.

Address forms (`resource_name`): a VISA resource string is used as given
(`ASRL/dev/ttyUSB0::INSTR`, `TCPIP::192.168.1.20::5025::SOCKET`, `TCPIP::192.168.1.20::INSTR`
for VXI-11, `USB0::0x2A8D::0x1102::MY59001234::0::INSTR` for USBTMC); a plain serial device
path (`/dev/ttyUSB0`, a pty, `COM3`) becomes an ASRL resource at the configured baud; `host:port`
becomes a raw SCPI socket. Every message ends in LF both ways.

Every failure is one of the typed exceptions of `drivers.errors`: a VISA timeout is
`InstrumentTimeout`; a closed socket, a port that went away (pyserial's SerialException, a
bare termios.error or OSError from a pty whose other side died) or a resource that cannot be
opened is `ConnectionLost` with the reason. pyvisa-py (0.8) reads a socket closed by the
instrument as "no data yet" until its timeout, so the transport looks at the socket itself
before each query and after a timeout, and reports the closed connection as ConnectionLost.
"""

from __future__ import annotations

import contextlib
import logging
import re
import socket
import termios
import threading
from collections.abc import Iterator
from typing import Any

from drivers.errors import ConnectionLost, InstrumentTimeout
from drivers.fd_wait import use_poll

log = logging.getLogger(__name__)

TERMINATION = "\n"
VISA_BACKEND = "@py"
_HOST_PORT = re.compile(r"(?P<host>[A-Za-z0-9_.-]+):(?P<port>\d{1,5})")
_SERIAL_PATH = re.compile(r"(/\S+|COM\d+)", re.IGNORECASE)
# what a broken link raises out of pyvisa/pyvisa-py: OSError covers pyserial's
# SerialException, socket errors and pyvisa's LibraryError; termios.error is not an OSError;
# ValueError is pyserial's "operation on a closed port"
_LINK_ERRORS: tuple[type[BaseException], ...] = (OSError, termios.error, ValueError, EOFError)


def resource_name(address: str) -> str:
    """The VISA resource string for a configured address (see the module docstring)."""
    text = address.strip()
    if "::" in text:
        return text
    if _SERIAL_PATH.fullmatch(text):
        com = re.fullmatch(r"COM(\d+)", text, re.IGNORECASE)  # Windows: ASRL3::INSTR
        return f"ASRL{com[1]}::INSTR" if com else f"ASRL{text}::INSTR"
    m = _HOST_PORT.fullmatch(text)
    if m:
        return f"TCPIP::{m['host']}::{m['port']}::SOCKET"
    raise ValueError(
        f"address {address!r} is neither a VISA resource string (ASRL/dev/ttyUSB0::INSTR, "
        "TCPIP::host::5025::SOCKET, TCPIP::host::INSTR, USB0::...::INSTR), a serial device path "
        "(/dev/ttyUSB0) nor host:port"
    )


def _visa_errors() -> tuple[type[BaseException], ...]:
    import pyvisa  # pyvisa (slow to import): only when a VISA instrument is opened

    return (pyvisa.errors.Error,)


def _is_timeout(exc: BaseException) -> bool:
    import pyvisa  # pyvisa (slow to import): only when a VISA instrument is opened

    return (
        isinstance(exc, pyvisa.errors.VisaIOError)
        and exc.error_code == pyvisa.constants.StatusCode.error_timeout
    )


class VisaTransport:
    """Line-oriented SCPI on one open pyvisa message-based resource, one exchange at a time.

    Args:
        resource: an open pyvisa `MessageBasedResource` (terminations set to LF).
        resource_name: its VISA resource string, for messages.
        instrument: the instrument's name in messages.
        timeout_s: wall seconds a reply may take.
    """

    def __init__(
        self, resource: Any, resource_name: str, *, instrument: str, timeout_s: float
    ) -> None:
        self._resource = resource
        self.resource_name = resource_name
        self.instrument = instrument
        self.timeout_s = timeout_s
        self._lock = threading.Lock()
        self._closed = False

    @classmethod
    def open(
        cls, address: str, *, baud: int = 115200, timeout_s: float = 1.0, instrument: str
    ) -> VisaTransport:
        """Open `address` with pyvisa-py; ConnectionLost says why it cannot be opened."""
        import pyvisa  # pyvisa (slow to import): only when a VISA instrument is opened

        use_poll()  # pyvisa-py and pyserial wait with select(): any descriptor number
        name = resource_name(address)
        options: dict[str, Any] = {
            "read_termination": TERMINATION,
            "write_termination": TERMINATION,
            "encoding": "latin-1",  # any byte decodes: garbage is a ProtocolError, not a crash
            "timeout": max(1, round(timeout_s * 1000)),
            "open_timeout": max(1, round(timeout_s * 1000)),
        }
        if name.upper().startswith("ASRL"):
            options["baud_rate"] = baud
        try:
            manager = pyvisa.ResourceManager(VISA_BACKEND)
            resource = manager.open_resource(name, **options)
        except Exception as exc:  # pyvisa-py raises bare Exception/ValueError on open
            raise ConnectionLost(
                f"cannot open the {instrument} at {name}: {_reason(exc)}; {_open_advice(name)}",
                instrument=instrument,
            ) from exc
        transport = cls(resource, name, instrument=instrument, timeout_s=timeout_s)
        try:
            sock = transport._socket()
            if sock is not None:  # a setting then SYST:ERR? must not wait for a delayed ACK
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            transport._discard_stale_input()  # a refused TCP connection shows here
        except OSError as exc:
            transport.close()
            raise ConnectionLost(
                f"cannot connect to the {instrument} at {name}: {_reason(exc)}; "
                f"{_open_advice(name)}",
                instrument=instrument,
            ) from exc
        except ConnectionLost:
            transport.close()
            raise
        return transport

    # ------------------------------------------------------------ exchanges

    def write(self, command: str) -> None:
        """Send one command line (no reply expected)."""
        with self._lock, self._mapped(command):
            self._discard_stale_input()
            self._resource.write(command)

    def query(self, command: str) -> str:
        """Send one command line and return its reply line (terminator stripped)."""
        with self._lock, self._mapped(command):
            self._discard_stale_input()
            self._resource.write(command)
            reply: str = self._resource.read()
            return reply.rstrip("\r\n")

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._resource.close()
        except Exception as exc:  # closing a dead link must not hide why it died
            log.warning("closing the %s (%s): %s", self.instrument, self.resource_name, exc)

    # ------------------------------------------------------------ error mapping

    @contextlib.contextmanager
    def _mapped(self, command: str) -> Iterator[None]:
        if self._closed:
            raise ConnectionLost(
                f"the {self.instrument}'s connection {self.resource_name} is closed",
                instrument=self.instrument,
            )
        try:
            yield
        except ConnectionLost:
            raise
        except _LINK_ERRORS + _visa_errors() as exc:
            if _is_timeout(exc):
                self._raise_closed_if_peer_gone(command)
                self._device_clear()
                raise InstrumentTimeout(
                    f"the {self.instrument} did not answer {command!r} within "
                    f"{self.timeout_s:g} s on {self.resource_name}: check that it is on, its "
                    "cable and (serial) the baud rate",
                    instrument=self.instrument,
                ) from exc
            raise ConnectionLost(
                f"the link to the {self.instrument} ({self.resource_name}) failed during "
                f"{command!r}: {_reason(exc)}; check its cable and power, then reconnect",
                instrument=self.instrument,
            ) from exc

    def _raise_closed_if_peer_gone(self, command: str) -> None:
        sock = self._socket()
        if sock is None:
            return
        try:
            gone = _socket_at_eof(sock)
        except OSError as exc:
            gone = True
            log.debug("probing %s: %s", self.resource_name, exc)
        if gone:
            raise ConnectionLost(
                f"the {self.instrument} ({self.resource_name}) closed the connection during "
                f"{command!r}; check that it is on and reachable, then reconnect",
                instrument=self.instrument,
            )

    def _device_clear(self) -> None:
        """After a timeout on VXI-11, HiSLIP, USBTMC or GPIB, a device clear drops the reply
        still pending in the instrument (sockets and serial ports are drained before each
        query instead)."""
        if self._socket() is not None or self.resource_name.upper().startswith("ASRL"):
            return
        try:
            self._resource.clear()
        except Exception as exc:  # the timeout is what gets reported
            log.info("device clear on %s after a timeout: %s", self.resource_name, exc)

    # ------------------------------------------------------------ stale input

    def _session(self) -> Any:
        """pyvisa-py's session object behind the resource (None if not pyvisa-py)."""
        sessions = getattr(getattr(self._resource, "visalib", None), "sessions", None)
        if not isinstance(sessions, dict):
            return None
        return sessions.get(getattr(self._resource, "session", None))

    def _socket(self) -> socket.socket | None:
        iface = getattr(self._session(), "interface", None)
        return iface if isinstance(iface, socket.socket) else None

    def _discard_stale_input(self) -> None:
        """Drop a late reply to an earlier (timed-out) query, so it cannot answer this one;
        a socket the instrument has closed is ConnectionLost here, before anything is sent."""
        import pyvisa  # pyvisa (slow to import): only when a VISA instrument is opened

        sock = self._socket()
        if sock is not None:
            self._resource.flush(pyvisa.constants.BufferOperation.discard_read_buffer_no_io)
            try:
                closed = _drain_socket(sock)
            except OSError as exc:
                raise ConnectionLost(
                    f"the connection to the {self.instrument} ({self.resource_name}) is down: "
                    f"{_reason(exc)}; check that it is on and reachable",
                    instrument=self.instrument,
                ) from exc
            if closed:
                raise ConnectionLost(
                    f"the {self.instrument} ({self.resource_name}) closed the connection; "
                    "check that it is on and reachable, then reconnect",
                    instrument=self.instrument,
                )
        elif self.resource_name.upper().startswith("ASRL"):
            try:
                self._resource.flush(pyvisa.constants.BufferOperation.discard_read_buffer)
            except _LINK_ERRORS + _visa_errors() as exc:
                raise ConnectionLost(
                    f"the {self.instrument}'s serial port {self.resource_name} failed: "
                    f"{_reason(exc)}; check its cable",
                    instrument=self.instrument,
                ) from exc


def _drain_socket(sock: socket.socket) -> bool:
    """Read and drop whatever is waiting; True if the peer has closed the connection."""
    while True:
        try:
            data = sock.recv(4096, socket.MSG_DONTWAIT)
        except (BlockingIOError, InterruptedError):
            return False
        if not data:
            return True
        log.info("discarded %d stale bytes from the instrument", len(data))


def _socket_at_eof(sock: socket.socket) -> bool:
    try:
        return sock.recv(1, socket.MSG_DONTWAIT | socket.MSG_PEEK) == b""
    except (BlockingIOError, InterruptedError):
        return False


def _reason(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 200 else text[:197] + "..."


def _open_advice(name: str) -> str:
    upper = name.upper()
    if upper.startswith("USB"):
        return (
            "USBTMC through pyvisa-py needs pyusb and libusb (pip install pyusb; apt install "
            "libusb-1.0-0) and read/write access to the device (a udev rule)"
        )
    if upper.startswith("ASRL"):
        return "check the port name, the cable, and that no other program holds the port"
    return "check the address, that the instrument is on and reachable and its port is open"
