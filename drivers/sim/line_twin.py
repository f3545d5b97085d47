"""A twin that speaks one ASCII line per request over TCP (ACUTROL, ESPEC P-300, raw SCPI).

Listening on loopback, the fault injection every twin offers (`drop`/`restore`: connections
closed and refused, then served again; `delay_s`: every answer late) and the line loop are
written here once; a family's twin gives only `reply(line)`.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging

from drivers.sim.world import World

log = logging.getLogger(__name__)


class LineTwin:
    """Base of the line-protocol twins.

    Subclasses set `terminator` (appended to every reply), `max_line_bytes` and
    `overlong_closes` (a longer request closes the connection, as a controller whose buffer
    overflows; else it is discarded and the connection kept), and implement `reply`."""

    name = "twin"
    terminator = b"\r\n"
    max_line_bytes = 4096
    overlong_closes = True

    def __init__(self, world: World, host: str = "127.0.0.1", port: int = 0) -> None:
        self.world = world
        self.host = host
        self.port = port
        self.delay_s = 0.0
        self.dropped = False
        self.requests = 0
        self._server: asyncio.Server | None = None
        self._writers: set[asyncio.StreamWriter] = set()

    def reply(self, line: str) -> str | None:
        """The answer to one request line (without terminators); None: no answer."""
        raise NotImplementedError

    # ------------------------------------------------------------ the twin contract

    async def start(self) -> None:
        self._server = await asyncio.start_server(
            self._serve, self.host, self.port, reuse_address=True, limit=self.max_line_bytes
        )
        self.port = self._server.sockets[0].getsockname()[1]

    def endpoint(self) -> str:
        return f"{self.host}:{self.port}"

    async def drop(self) -> None:
        """Close every connection and stop listening (a pulled cable, a crashed unit)."""
        if self.dropped or self._server is None:
            return
        self.dropped = True
        await self._close_all()

    async def restore(self) -> None:
        if self.dropped:
            self.dropped = False
            await self.start()

    async def shutdown(self) -> None:
        await self._close_all()

    # ------------------------------------------------------------ serving

    async def _close_all(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            server.close()
        writers = list(self._writers)
        self._writers.clear()
        for writer in writers:
            writer.close()
        for writer in writers:
            with contextlib.suppress(ConnectionError, OSError):
                await writer.wait_closed()
        if server is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(server.wait_closed(), 1.0)

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._writers.add(writer)
        try:
            while not self.dropped:
                try:
                    raw = await reader.readline()
                except ValueError:  # longer than max_line_bytes
                    log.info("%s: over-long request", self.name)
                    if self.overlong_closes:
                        return
                    continue
                if not raw:
                    return
                self.requests += 1
                if self.delay_s > 0:
                    await asyncio.sleep(self.delay_s)
                if self.dropped:
                    return
                answer = self._reply(raw.decode("ascii", "replace").strip())
                if answer is not None and not writer.is_closing():
                    writer.write(answer.encode("ascii", "replace") + self.terminator)
                    await writer.drain()
        except (ConnectionError, OSError, asyncio.IncompleteReadError):
            return
        finally:
            self._writers.discard(writer)
            writer.close()

    def _reply(self, line: str) -> str | None:
        try:
            return self.reply(line)
        except Exception:  # a twin bug must not kill the bench's event loop
            log.exception("%s failed on %r", self.name, line)
            return None
