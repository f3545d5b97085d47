"""A line-oriented TCP client (one request line, one reply line) with typed errors.

For ASCII instrument protocols over a socket (the ACUTROL command language). A refused
connection or a closed socket becomes `ConnectionLost`, a reply later than the wall timeout
`InstrumentTimeout`. After a timeout the socket is closed, so a late reply can never be taken
for the answer to the next request; the next request reconnects.
"""

from __future__ import annotations

import socket
import threading

from drivers.errors import ConnectionLost, InstrumentTimeout, ProtocolError

MAX_REPLY_BYTES = 65536


class LineLink:
    """One TCP connection; `query(line)` sends `line` + `send_end`, returns the reply line.

    `timeout_s` is wall seconds for connecting and for each reply.
    """

    def __init__(
        self, host: str, port: int, *, timeout_s: float = 1.0, instrument: str = "instrument",
        send_end: bytes = b"\r\n",
    ) -> None:
        self.host = host
        self.port = port
        self.timeout_s = timeout_s
        self.instrument = instrument
        self.send_end = send_end
        self._sock: socket.socket | None = None
        self._rx = bytearray()
        self._lock = threading.Lock()

    @property
    def where(self) -> str:
        return f"{self.instrument} at {self.host}:{self.port}"

    def connect(self) -> None:
        with self._lock:
            self._ensure_connected()

    def _ensure_connected(self) -> socket.socket:
        if self._sock is not None:
            return self._sock
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.timeout_s)
        except OSError as exc:
            raise ConnectionLost(
                f"cannot connect to the {self.where}: check that it is powered, its network "
                f"cable is in and the address in the station configuration is right ({exc})",
                instrument=self.instrument,
            ) from exc
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock = sock
        self._rx.clear()
        return sock

    def _drop(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        self._rx.clear()

    def query(self, line: str) -> str:
        """Send one line, return the reply line without its terminator."""
        with self._lock:
            sock = self._ensure_connected()
            try:
                sock.sendall(line.encode("ascii") + self.send_end)
                return self._read_line(sock, line)
            except TimeoutError as exc:
                self._drop()  # a late reply must not answer the next request
                raise InstrumentTimeout(
                    f"the {self.where} did not answer {line!r} within {self.timeout_s:g} s: "
                    "check the controller is running; the station reconnects on the next "
                    "request",
                    instrument=self.instrument,
                ) from exc
            except OSError as exc:
                self._drop()
                raise ConnectionLost(
                    f"the connection to the {self.where} dropped during {line!r}: check the "
                    f"network cable and the controller's power, then retry ({exc})",
                    instrument=self.instrument,
                ) from exc

    def _read_line(self, sock: socket.socket, line: str) -> str:
        while b"\n" not in self._rx:
            chunk = sock.recv(4096)
            if not chunk:
                raise ConnectionResetError("the controller closed the connection")
            self._rx += chunk
            if len(self._rx) > MAX_REPLY_BYTES:
                self._drop()
                raise ProtocolError(
                    f"the {self.where} sent more than {MAX_REPLY_BYTES} bytes without a line "
                    f"end in reply to {line!r}",
                    instrument=self.instrument,
                )
        end = self._rx.index(b"\n")
        reply = bytes(self._rx[:end]).rstrip(b"\r")
        del self._rx[: end + 1]
        try:
            return reply.decode("ascii")
        except UnicodeDecodeError as exc:
            self._drop()
            raise ProtocolError(
                f"the {self.where} answered {line!r} with non-ASCII bytes {reply!r}",
                instrument=self.instrument,
            ) from exc

    def query_more(self, line: str) -> str:
        """The next line of a multi-line reply to `line` (already sent by `query`)."""
        with self._lock:
            if self._sock is None:
                raise ConnectionLost(
                    f"the connection to the {self.where} dropped before the rest of its reply "
                    f"to {line!r}; retry", instrument=self.instrument,
                )
            try:
                return self._read_line(self._sock, line)
            except TimeoutError as exc:
                self._drop()
                raise InstrumentTimeout(
                    f"the {self.where} sent only part of its reply to {line!r} within "
                    f"{self.timeout_s:g} s: check its baud and mode", instrument=self.instrument,
                ) from exc
            except OSError as exc:
                self._drop()
                raise ConnectionLost(
                    f"the connection to the {self.where} dropped during {line!r} ({exc})",
                    instrument=self.instrument,
                ) from exc

    def close(self) -> None:
        with self._lock:
            self._drop()
