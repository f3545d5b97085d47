"""Serial twins on pseudo-terminals: the supply's SCPI port and one port per fixture socket.

The station opens the slave side (`path`) with pyserial like a real USB-serial port. The bench
keeps the slave fd open too, so its master never reads EIO when the station closes the port.
Output goes through a non-blocking outgoing buffer; a fixture's buffer is its FIFO: when the
station does not read fast enough and the FIFO is full, new sample frames are dropped (and
counted), as an overflowing UART would.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import tty
from collections.abc import Callable

from drivers.sim.fixture import FixtureSocket
from drivers.sim.world import World

log = logging.getLogger(__name__)
MAX_LINE = 4096


MAX_PTYS_SKIPPED = 64


def _never_held(path: str) -> bool:
    return False


class PtyPort:
    """A pseudo-terminal pair: the slave path for the station, the master side here.

    `held_elsewhere(path)` says whether a station process still holds a pty path (its
    instrument lock, from a bench that died); such a number is passed over, so no station
    ever commands this bench through an address it still keeps for another. The bench's
    process sets it (station/cli/bench.py); by default nothing is held."""

    held_elsewhere: Callable[[str], bool] = staticmethod(_never_held)

    def __init__(self, loop: asyncio.AbstractEventLoop, on_line: Callable[[str], None]) -> None:
        self._loop = loop
        self._on_line = on_line
        self.master, self.slave = self._open_free_pty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)
        self._out = bytearray()
        self._in = bytearray()
        self._writing = False
        self._closed = False
        loop.add_reader(self.master, self._readable)

    @classmethod
    def _open_free_pty(cls) -> tuple[int, int]:
        """A pty pair whose path no station holds; the pairs passed over stay open until
        then, so the kernel does not hand the same number out again at once."""
        passed_over: list[int] = []
        try:
            for _ in range(MAX_PTYS_SKIPPED):
                master, slave = os.openpty()
                if not cls.held_elsewhere(os.ttyname(slave)):
                    return master, slave
                log.info("pty %s is still held by a station process: passed over",
                         os.ttyname(slave))
                passed_over += [master, slave]
            raise OSError(
                f"every one of {MAX_PTYS_SKIPPED} new pseudo-terminals is held by a station "
                "process: end the stations left running from benches that stopped"
            )
        finally:
            for fd in passed_over:
                os.close(fd)

    @property
    def pending_bytes(self) -> int:
        return len(self._out)

    def _readable(self) -> None:
        try:
            data = os.read(self.master, 65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            return  # EIO while nobody holds the slave; we hold it, so this is transient
        self._in += data
        while True:
            idx = self._in.find(b"\n")
            if idx < 0:
                break
            line = self._in[:idx].decode("ascii", "replace").strip("\r")
            del self._in[: idx + 1]
            try:
                self._on_line(line)
            except Exception:  # a bug in a twin must not kill the bench's event loop
                log.exception("serial twin failed on %r", line)
        if len(self._in) > MAX_LINE:
            del self._in[:]

    def write(self, data: bytes) -> None:
        if self._closed or not data:
            return
        self._out += data
        self._flush()

    def _flush(self) -> None:
        while self._out:
            try:
                n = os.write(self.master, self._out)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                self._out.clear()
                break
            del self._out[:n]
        if self._out and not self._writing:
            self._loop.add_writer(self.master, self._flush)
            self._writing = True
        elif not self._out and self._writing:
            self._loop.remove_writer(self.master)
            self._writing = False

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._loop.remove_reader(self.master)
        if self._writing:
            self._loop.remove_writer(self.master)
        for fd in (self.master, self.slave):
            with contextlib.suppress(OSError):
                os.close(fd)


class SupplyTwin:
    """The supply's SCPI port: one reply line per query, nothing for a setting."""

    def __init__(self, world: World, loop: asyncio.AbstractEventLoop) -> None:
        self.world = world
        self.port = PtyPort(loop, self._line)

    def _line(self, line: str) -> None:
        self.world.advance()
        reply = self.world.supply.handle(line)
        self.world.advance()
        if reply is not None:
            self.port.write(reply.encode("ascii") + b"\n")

    def close(self) -> None:
        self.port.close()


class FixtureTwin:
    """One fixture socket's serial port: commands in, reply and sample frames out."""

    def __init__(
        self, world: World, socket: FixtureSocket, loop: asyncio.AbstractEventLoop, fifo_bytes: int
    ) -> None:
        self.world = world
        self.socket = socket
        self.fifo_bytes = fifo_bytes
        self.fifo_peak_bytes = 0
        self.port = PtyPort(loop, self._line)

    def _line(self, line: str) -> None:
        t = self.world.advance()
        self._send_samples(self.socket.produce(t))
        self.port.write(self.socket.handle_line(line, t))

    def tick(self, t_s: float) -> None:
        """Send the sample frames due up to world time `t_s`."""
        self._send_samples(self.socket.produce(t_s))

    def send_samples(self, frames: bytes) -> None:
        """Send sample frames the world produced for this socket (`World.produce_all`)."""
        self._send_samples(frames)

    def _send_samples(self, frames: bytes) -> None:
        if not frames:
            return
        room = self.fifo_bytes - self.port.pending_bytes
        if len(frames) > room:
            size = self.socket.frame_size
            keep = max(0, room // size) * size
            self.socket.frames_overflowed += (len(frames) - keep) // size
            frames = frames[:keep]
        self.port.write(frames)
        self.fifo_peak_bytes = max(self.fifo_peak_bytes, self.port.pending_bytes)

    def close(self) -> None:
        self.port.close()
