"""Read fixture sample streams straight off the bench's ptys (tests and benchmarks).

Deliberately independent of the station's part-link driver: it opens each port with
pyserial (raw mode), sends fixture commands, and decodes with `FrameParser`, reading every
port from one thread with poll().
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import numpy as np
import serial

from drivers.fd_wait import select_by_poll, use_poll
from drivers.fixture_protocol import FrameParser


@dataclass
class StreamCount:
    """What one port delivered."""

    path: str
    frames_ok: int = 0
    frames_lost: int = 0
    frames_corrupted: int = 0
    bytes_discarded: int = 0
    replies: list[str] = field(default_factory=list)
    first_time_s: float | None = None
    last_time_s: float | None = None
    first_seq: int | None = None  # sequence counters at the edges: drops before the first or
    last_seq: int | None = None  # after the last delivered frame leave no gap to count
    rate_code_sum: int = 0


def scpi(path: str, *lines: str, timeout_s: float = 2.0) -> list[str]:
    """Send SCPI lines to the supply port; return the reply of every query (ending in ?).

    Ends with a query of its own when the last line is a setting, so every setting has been
    carried out when this returns.
    """
    replies = []
    sync = () if lines and lines[-1].strip().endswith("?") else ("OUTP?",)
    use_poll()  # pyserial's own waits, at any descriptor number
    with serial.Serial(path, timeout=timeout_s) as port:
        for line in (*lines, *sync):
            port.write(line.encode("ascii") + b"\n")
            if line.strip().endswith("?"):
                reply = port.readline()
                if not reply.endswith(b"\n"):
                    raise TimeoutError(f"no answer to {line!r} on {path} within {timeout_s} s")
                replies.append(reply.decode("ascii").strip())
    return replies[: len(replies) - len(sync)]


def power_parts(path: str, supply_v: float = 5.0, current_limit_a: float = 0.5) -> None:
    """Set the supply and switch its output on (the parts in the fixture power up)."""
    scpi(path, f"VOLT {supply_v}", f"CURR {current_limit_a}", "OUTP ON", "OUTP?")


class StreamProbe:
    """Several fixture ports opened at once."""

    def __init__(self, paths: list[str]) -> None:
        use_poll()
        self.ports = [serial.Serial(p, baudrate=921600, timeout=0) for p in paths]
        self.parsers = [FrameParser() for _ in paths]
        self.counts = [StreamCount(p) for p in paths]

    def close(self) -> None:
        for port in self.ports:
            port.close()

    def __enter__(self) -> StreamProbe:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _feed(self, i: int, data: bytes) -> None:
        res = self.parsers[i].feed(data)
        c = self.counts[i]
        c.frames_ok += len(res.seq)
        c.frames_lost += res.frames_lost
        c.frames_corrupted += res.frames_corrupted
        c.bytes_discarded += res.bytes_discarded
        c.replies.extend(res.replies)
        if len(res.seq):
            if c.first_time_s is None:
                c.first_time_s = float(res.time_s[0])
                c.first_seq = int(res.seq[0])
            c.last_time_s = float(res.time_s[-1])
            c.last_seq = int(res.seq[-1])
            c.rate_code_sum += int(np.sum(res.rate_code))

    def pump(self, timeout_s: float = 0.05) -> int:
        """Read whatever is waiting on every port; returns the bytes read."""
        fds = [p.fileno() for p in self.ports]
        ready, _, _ = select_by_poll(fds, [], [], timeout_s)  # any descriptor number
        total = 0
        for fd in ready:
            i = fds.index(fd)
            chunks = []
            size = 0
            while size < (1 << 20):  # a pty hands out ~4 KB per read: gather, then parse once
                try:
                    data = os.read(fd, 1 << 20)
                except BlockingIOError:
                    break
                if not data:
                    break
                chunks.append(data)
                size += len(data)
            if chunks:
                total += size
                self._feed(i, b"".join(chunks))
        return total

    def wait_frames(self, i: int, frames: int = 1, timeout_s: float = 5.0) -> None:
        """Read until port `i` has delivered at least `frames` sample frames."""
        deadline = time.monotonic() + timeout_s
        while self.counts[i].frames_ok < frames:
            if time.monotonic() > deadline:
                raise TimeoutError(
                    f"{self.ports[i].port}: fewer than {frames} frames in {timeout_s} s"
                )
            self.pump(0.02)

    def drain(self, quiet_s: float = 0.05, timeout_s: float = 5.0) -> None:
        """Read until no port has delivered anything for `quiet_s` wall seconds."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.pump(quiet_s) == 0:
                return
        raise TimeoutError(f"the ports kept sending for {timeout_s} s")

    def command(self, i: int, line: str, timeout_s: float = 5.0) -> str:
        """Send a command to port `i` and wait for its reply (samples keep being decoded)."""
        before = len(self.counts[i].replies)
        self.ports[i].write(line.encode("ascii") + b"\n")
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.pump(0.02)
            if len(self.counts[i].replies) > before:
                return self.counts[i].replies[before]
        raise TimeoutError(f"no reply to {line!r} on {self.ports[i].port} within {timeout_s} s")

    def command_all(self, line: str) -> list[str]:
        return [self.command(i, line) for i in range(len(self.ports))]

    def stream(self, odr_hz: int, frames: int | None = None, wall_s: float | None = None) -> None:
        """START every port, read until each delivered `frames` (or `wall_s` passed), STOP."""
        for i in range(len(self.ports)):
            self.command(i, "STOP")
        self.drain()  # whatever an earlier stream left in the ports is not this stream's
        for i, parser in enumerate(self.parsers):
            parser.reset_sequence()
            self.counts[i] = StreamCount(self.counts[i].path)
            self.command(i, f"ODR {odr_hz}")
        for i in range(len(self.ports)):
            reply = self.command(i, "START")
            if not reply.startswith("OK"):
                raise RuntimeError(f"{self.ports[i].port}: START refused: {reply}")
        start = time.monotonic()
        base = [c.frames_ok for c in self.counts]
        while True:
            self.pump(0.02)
            done_frames = frames is not None and all(
                c.frames_ok - b >= frames for c, b in zip(self.counts, base, strict=True)
            )
            done_time = wall_s is not None and time.monotonic() - start >= wall_s
            if done_frames or done_time:
                break
        for i in range(len(self.ports)):
            self.command(i, "STOP", timeout_s=60.0)  # the reply queues behind a full FIFO
