"""The one expected-protocol helper of the byte-level driver tests (after PyMeasure's
`expected_protocol`): the test gives the exact list of (bytes written, bytes replied) pairs,
the driver talks to a fake transport that checks every message it writes against the next
pair and answers with that pair's reply; the test fails if the driver writes anything else,
or leaves pairs unused.

`ExpectedProtocol` holds the pairs and judges each message. The transports put it where the
driver looks for its instrument:

- `TcpPeer`: a server on a loopback port, messages framed as lines (`LINES`, up to LF) or as
  Modbus TCP (`MODBUS`: the MBAP header checked and stripped, the reply PDU wrapped in one);
- `SerialPeer`: an object with pyserial's API, in the test's own thread;
- tests/drivers/_scpi_fakes.py: a SOCKET or ASRL VISA resource (a pty) for pyvisa.

`lines_from` and `write_all` are the pty side of every fake serial instrument (the SCPI
supply, the part fixtures).

`finish(peer, *drivers)` closes the drivers and the peer and asserts the pairs were used up,
no other message seen; `expected_protocol(peer, *drivers)` does that at the end of a block.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import struct
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, Protocol


@dataclass
class Pair:
    """One exchange: the exact bytes the driver must write, and what the instrument does."""

    request: bytes  # terminator included (for Modbus: the PDU, function code + data)
    reply: bytes | None = b""  # sent back verbatim; None or b"": no answer
    delay_s: float = 0.0  # wall seconds before answering (a slow instrument)
    close: bool = False  # close the connection instead of answering


class ExpectedProtocol:
    """The pairs a driver must go through, in order; every mismatch is kept in `errors`."""

    def __init__(self, pairs: list[Pair] | list[tuple[bytes, bytes]]) -> None:
        self.script = [p if isinstance(p, Pair) else Pair(*p) for p in pairs]
        self.errors: list[str] = []
        self.received: list[bytes] = []

    @property
    def done(self) -> bool:
        return not self.script

    def answer(self, message: bytes) -> Pair | None:
        """The pair `message` takes (after its delay), None once the pairs are used up."""
        self.received.append(message)
        if not self.script:
            self.errors.append(f"unexpected {message!r} after the last pair")
            return None
        pair = self.script.pop(0)
        if message != pair.request:
            self.errors.append(f"expected {pair.request!r}, got {message!r}")
        if pair.delay_s:
            time.sleep(pair.delay_s)
        return pair

    def assert_done(self) -> None:
        assert self.errors == [], self.errors
        assert self.done, f"unused pairs: {self.script}"


class _Closable(Protocol):
    def close(self) -> None: ...


def finish(peer: Any, *drivers: _Closable) -> None:
    """Close the drivers, then the peer; then the pairs must all have been used, as given."""
    for driver in drivers:
        driver.close()
    peer.close()
    peer.assert_done()


@contextlib.contextmanager
def expected_protocol(peer: Any, *drivers: _Closable) -> Iterator[Any]:
    """`with expected_protocol(peer, driver):` the block talks to the driver; at its end
    `finish` checks the exchange (not when the block raised: its error says more)."""
    yield peer
    finish(peer, *drivers)


# ---------------------------------------------------------------- framings for TcpPeer

@dataclass(frozen=True)
class Framing:
    """How messages travel: `read` takes one from the connection (None: it closed) with what
    its reply needs (the Modbus transaction id and unit), `wrap` frames a reply."""

    read: Callable[[Stream, TcpPeer], tuple[bytes, Any] | None]
    wrap: Callable[[bytes, Any], bytes]


def _read_line(stream: Stream, protocol: TcpPeer) -> tuple[bytes, Any] | None:
    line = stream.read_until(b"\n")
    return None if line is None else (line, None)


def _read_mbap(stream: Stream, protocol: TcpPeer) -> tuple[bytes, Any] | None:
    header = stream.read_exact(7)
    if header is None:
        return None
    tid, proto, length, unit = struct.unpack(">HHHB", header)
    pdu = stream.read_exact(length - 1)
    if pdu is None:
        return None
    if proto != 0 or unit != protocol.unit:
        protocol.errors.append(f"bad MBAP header {header.hex()}")
    return pdu, (tid, unit)


LINES = Framing(_read_line, lambda reply, _: reply)
MODBUS = Framing(
    _read_mbap,
    lambda reply, state: struct.pack(">HHHB", state[0], 0, len(reply) + 1, state[1]) + reply,
)


class Stream:
    """Buffered reads from a connection that give up when the peer is stopping."""

    def __init__(self, conn: socket.socket, stop: threading.Event) -> None:
        self.conn, self.stop = conn, stop
        self.buf = b""

    def _fill(self) -> bool:
        while not self.stop.is_set():
            try:
                chunk = self.conn.recv(4096)
            except TimeoutError:
                continue
            except OSError:
                return False
            if not chunk:
                return False
            self.buf += chunk
            return True
        return False

    def read_exact(self, n: int) -> bytes | None:
        while len(self.buf) < n:
            if not self._fill():
                return None
        out, self.buf = self.buf[:n], self.buf[n:]
        return out

    def read_until(self, end: bytes) -> bytes | None:
        while end not in self.buf:
            if not self._fill():
                return None
        i = self.buf.index(end) + len(end)
        out, self.buf = self.buf[:i], self.buf[i:]
        return out


class TcpPeer(ExpectedProtocol):
    """The pairs served on 127.0.0.1:`port`, one connection at a time, framed by `framing`.
    A message after the last pair is an error and closes the connection."""

    def __init__(self, pairs: list[Pair], framing: Framing = LINES, unit: int = 1) -> None:
        super().__init__(pairs)
        self.framing = framing
        self.unit = unit  # the Modbus unit id the requests must carry
        self._sock = socket.create_server(("127.0.0.1", 0))
        self._sock.settimeout(0.1)
        self.port = self._sock.getsockname()[1]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    @property
    def requests(self) -> list[bytes]:  # the Modbus tests' name for what was received
        return self.received

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except OSError:
                continue
            with conn:
                conn.settimeout(0.1)
                self._converse(Stream(conn, self._stop))

    def _converse(self, stream: Stream) -> None:
        while not self._stop.is_set():
            got = self.framing.read(stream, self)
            if got is None:
                return
            message, state = got
            pair = self.answer(message)
            if pair is None or pair.close:
                return
            if pair.reply:
                try:
                    stream.conn.sendall(self.framing.wrap(pair.reply, state))
                except OSError:
                    return

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self._sock.close()

    def __enter__(self) -> TcpPeer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class SerialPeer(ExpectedProtocol):
    """The pairs behind pyserial's API (write, read, readline, in_waiting,
    reset_input_buffer, close, timeout): each write is checked and its reply queued."""

    def __init__(self, pairs: list[Pair] | list[tuple[bytes, bytes]],
                 timeout: float = 0.05) -> None:
        super().__init__(pairs)
        self.timeout = timeout
        self._rx = bytearray()
        self.is_open = True

    @property
    def written(self) -> list[bytes]:
        return self.received

    def write(self, data: bytes) -> int:
        pair = self.answer(bytes(data))
        if pair is not None and pair.reply:
            self._rx += pair.reply
        return len(data)

    def flush(self) -> None:
        pass

    @property
    def in_waiting(self) -> int:
        return len(self._rx)

    def read(self, size: int = 1) -> bytes:
        if not self._rx:
            time.sleep(self.timeout)
        out = bytes(self._rx[:size])
        del self._rx[:size]
        return out

    def readline(self) -> bytes:
        i = self._rx.find(b"\n")
        if i < 0:
            time.sleep(self.timeout)
            out = bytes(self._rx)
            self._rx.clear()
            return out
        out = bytes(self._rx[: i + 1])
        del self._rx[: i + 1]
        return out

    def reset_input_buffer(self) -> None:
        self._rx.clear()

    def close(self) -> None:
        self.is_open = False


def lines_from(fd: int, stop: threading.Event, poll_s: float = 0.05) -> Iterator[bytes]:
    """Each line written to `fd` (a pty's master), its LF taken off, until `stop` is set or
    the fd closes."""
    buf = b""
    while not stop.is_set():
        try:
            if not select.select([fd], [], [], poll_s)[0]:
                continue
            chunk = os.read(fd, 4096)
        except (OSError, ValueError):
            return
        if not chunk:
            return
        buf += chunk
        while b"\n" in buf:
            line, buf = buf.split(b"\n", 1)
            yield line


def write_all(fd: int, data: bytes) -> None:
    """All of `data` to `fd` (a pty takes it in pieces when the reader is slow)."""
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]
