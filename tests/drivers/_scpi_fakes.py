"""The expected-protocol pairs (tests/drivers/expected_protocol.py) as a SCPI instrument on a
real loopback socket or pseudo-terminal, one level below pyvisa: every message the driver
sends is checked byte for byte against the next pair, and its reply bytes go back, so the
tests see exactly what is on the wire, terminators included.
"""

from __future__ import annotations

import contextlib
import os
import socket
import threading
import tty

from tests.drivers.expected_protocol import ExpectedProtocol, Pair, lines_from

NO_ERROR = b'+0,"No error"\n'


class ScriptedScpi(ExpectedProtocol):
    """Serves the pairs on `kind` ("tcp": a SOCKET resource, "pty": an ASRL resource); a
    reply may lack the LF, or be several lines."""

    def __init__(self, script: list[Pair], kind: str = "tcp") -> None:
        super().__init__(script)
        self.kind = kind
        self._stop = threading.Event()
        self._conn: socket.socket | None = None
        if kind == "tcp":
            self._server = socket.create_server(("127.0.0.1", 0))
            self.port = self._server.getsockname()[1]
            self.resource = f"TCPIP::127.0.0.1::{self.port}::SOCKET"
        else:
            self.master, self.slave = os.openpty()
            tty.setraw(self.slave)
            self.path = os.ttyname(self.slave)
            self.resource = f"ASRL{self.path}::INSTR"
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    # ------------------------------------------------------------ serving

    def _run(self) -> None:
        if self.kind == "tcp":
            self._server.settimeout(0.05)
            while not self._stop.is_set():
                try:
                    conn, _ = self._server.accept()
                except (TimeoutError, OSError):
                    continue
                self._conn = conn
                self._serve(conn.fileno(), lambda data, c=conn: c.sendall(data))
                with contextlib.suppress(OSError):
                    conn.close()
        else:
            master = self.master
            self._serve(master, lambda data: os.write(master, data))

    def _serve(self, fd: int, send: object) -> None:
        for message in lines_from(fd, self._stop):
            if self._answer(message + b"\n", send):
                return

    def _answer(self, message: bytes, send: object) -> bool:
        """True when the connection is to be closed."""
        step = self.answer(message)
        if step is None:
            return False
        if step.close:
            self._close_link()
            return True
        if step.reply:
            try:
                send(step.reply)  # type: ignore[operator]
            except OSError:
                return True
        return False

    def _close_link(self) -> None:
        if self.kind == "tcp":
            if self._conn is not None:
                with contextlib.suppress(OSError):
                    self._conn.shutdown(socket.SHUT_RDWR)
                    self._conn.close()
            self._stop.set()
            with contextlib.suppress(OSError):
                self._server.close()
        else:  # the other side of a pty dies: the slave reads EIO from now on
            self._close_fd("master")

    def _close_fd(self, which: str) -> None:
        fd = getattr(self, which)
        if fd >= 0:
            setattr(self, which, -1)  # never close a number the process may have reused
            with contextlib.suppress(OSError):
                os.close(fd)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        if self.kind == "tcp":
            with contextlib.suppress(OSError):
                self._server.close()
        else:
            self._close_fd("master")
            self._close_fd("slave")
