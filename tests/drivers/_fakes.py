"""Byte-level fakes for driver tests (pymeasure's expected-protocol idea).

`ExpectedModbus` is a Modbus TCP server on localhost that checks each request's PDU against a
script and answers with the scripted PDU. `ExpectedSerial` is a serial-port stand-in that
checks each write against a script and queues the scripted reply. `ManualClock` is a station
clock that advances only when slept on, so timeouts are tested instantly and exactly.
"""

from __future__ import annotations

import socket
import struct
import threading
import time
from dataclasses import dataclass


@dataclass
class Exchange:
    request: bytes  # expected PDU: function code + data
    reply: bytes | None  # PDU to answer with; None: no answer
    delay_s: float = 0.0  # wall seconds before answering
    close: bool = False  # close the connection instead of answering


def read_pdu(address: int, count: int) -> bytes:
    return struct.pack(">BHH", 3, address, count)


def read_reply(regs: list[int]) -> bytes:
    return struct.pack(f">BB{len(regs)}H", 3, 2 * len(regs), *[r & 0xFFFF for r in regs])


def write_pdu(address: int, value: int) -> bytes:
    return struct.pack(">BHH", 6, address, value & 0xFFFF)


def write_many_pdu(address: int, regs: list[int]) -> bytes:
    return struct.pack(
        f">BHHB{len(regs)}H", 16, address, len(regs), 2 * len(regs), *[r & 0xFFFF for r in regs]
    )


def write_many_reply(address: int, count: int) -> bytes:
    return struct.pack(">BHH", 16, address, count)


def exception_reply(function: int, code: int) -> bytes:
    return bytes([function | 0x80, code])


def str_regs(text: str, count: int) -> list[int]:
    raw = text.encode().ljust(2 * count, b"\0")
    return [int.from_bytes(raw[i : i + 2], "big") for i in range(0, 2 * count, 2)]


def pair(value: int) -> list[int]:
    value &= 0xFFFFFFFF
    return [value >> 16, value & 0xFFFF]


class ExpectedModbus:
    """Scripted Modbus TCP server; `errors` lists every mismatch, `done` when all consumed."""

    def __init__(self, script: list[Exchange], unit: int = 1) -> None:
        self.script = list(script)
        self.unit = unit
        self.errors: list[str] = []
        self.requests: list[bytes] = []
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

    def _recv_exact(self, conn: socket.socket, n: int) -> bytes | None:
        data = b""
        while len(data) < n and not self._stop.is_set():
            try:
                chunk = conn.recv(n - len(data))
            except TimeoutError:
                continue
            except OSError:
                return None
            if not chunk:
                return None
            data += chunk
        return data if len(data) == n else None

    def _handle(self, conn: socket.socket) -> None:
        while not self._stop.is_set():
            header = self._recv_exact(conn, 7)
            if header is None:
                return
            tid, proto, length, unit = struct.unpack(">HHHB", header)
            pdu = self._recv_exact(conn, length - 1)
            if pdu is None:
                return
            self.requests.append(pdu)
            if proto != 0 or unit != self.unit:
                self.errors.append(f"bad MBAP header {header.hex()}")
            if not self.script:
                self.errors.append(f"unexpected request {pdu.hex()}")
                return
            ex = self.script.pop(0)
            if pdu != ex.request:
                self.errors.append(f"expected {ex.request.hex()}, got {pdu.hex()}")
            if ex.delay_s:
                time.sleep(ex.delay_s)
            if ex.close:
                return
            if ex.reply is not None:
                try:
                    conn.sendall(struct.pack(">HHHB", tid, 0, len(ex.reply) + 1, unit) + ex.reply)
                except OSError:
                    return

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self._sock.close()

    def __enter__(self) -> ExpectedModbus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class ExpectedSerial:
    """Serial-port stand-in: each write must equal the next scripted line; its reply is queued.

    Has the parts of pyserial's API the drivers use: write, read, readline, in_waiting,
    reset_input_buffer, close, timeout.
    """

    def __init__(self, script: list[tuple[bytes, bytes]], timeout: float = 0.05) -> None:
        self.script = list(script)
        self.errors: list[str] = []
        self.written: list[bytes] = []
        self.timeout = timeout
        self._rx = bytearray()
        self.is_open = True

    @property
    def done(self) -> bool:
        return not self.script

    def write(self, data: bytes) -> int:
        self.written.append(bytes(data))
        if not self.script:
            self.errors.append(f"unexpected write {data!r}")
            return len(data)
        expected, reply = self.script.pop(0)
        if data != expected:
            self.errors.append(f"expected {expected!r}, got {data!r}")
        self._rx += reply
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


class ManualClock:
    """Station clock that moves only when someone sleeps on it (speed irrelevant)."""

    def __init__(self, speed: float = 1.0) -> None:
        self._now = 0.0
        self._speed = speed
        self.slept_s = 0.0

    @property
    def speed(self) -> float:
        return self._speed

    def now_s(self) -> float:
        return self._now

    def sleep_s(self, duration_s: float) -> None:
        if duration_s > 0:
            self._now += duration_s
            self.slept_s += duration_s

    def wall_timeout_s(self, duration_s: float) -> float:
        return duration_s / self._speed
