"""Scripted line-protocol TCP server for byte-level tests of ASCII drivers.

Each received line (bytes up to and including LF) must equal the next scripted request; the
scripted reply is sent back verbatim (or the connection closed, or nothing sent).
"""

from __future__ import annotations

import socket
import threading
import time
from dataclasses import dataclass


@dataclass
class Line:
    request: bytes  # expected bytes, terminator included
    reply: bytes | None  # sent verbatim; None: no answer
    delay_s: float = 0.0
    close: bool = False


class ExpectedLines:
    def __init__(self, script: list[Line]) -> None:
        self.script = list(script)
        self.errors: list[str] = []
        self.received: list[bytes] = []
        self._sock = socket.create_server(("127.0.0.1", 0))
        self._sock.settimeout(0.1)
        self.port = self._sock.getsockname()[1]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    @property
    def done(self) -> bool:
        return not self.script

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except OSError:
                continue
            with conn:
                conn.settimeout(0.1)
                self._handle(conn)

    def _handle(self, conn: socket.socket) -> None:
        buf = b""
        while not self._stop.is_set():
            while b"\n" not in buf:
                try:
                    chunk = conn.recv(4096)
                except TimeoutError:
                    if self._stop.is_set():
                        return
                    continue
                except OSError:
                    return
                if not chunk:
                    return
                buf += chunk
            end = buf.index(b"\n") + 1
            line, buf = buf[:end], buf[end:]
            self.received.append(line)
            if not self.script:
                self.errors.append(f"unexpected line {line!r}")
                return
            step = self.script.pop(0)
            if line != step.request:
                self.errors.append(f"expected {step.request!r}, got {line!r}")
            if step.delay_s:
                time.sleep(step.delay_s)
            if step.close:
                return
            if step.reply is not None:
                try:
                    conn.sendall(step.reply)
                except OSError:
                    return

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self._sock.close()
