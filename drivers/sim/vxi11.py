"""A VXI-11 core channel (VXIbus Consortium VXI-11 rev. 1.0, ONC RPC program 0x0607AF
version 1 over TCP, RFC 5531 record marking, XDR), serving one SCPI twin the way a LAN
instrument serves its `TCPIP::host::INSTR` resource.

A client reaches it without the portmapper by naming the port, as pyvisa-py allows
(`TCPIP::127.0.0.1,<port>::inst0::INSTR`): a twin on a shared machine cannot take the
privileged port 111. device_write collects a message until its END flag, device_read returns
the response (reason END), device_readstb the status byte (MAV while a response waits),
device_clear empties both (IEEE 488.2 device clear); locks, remote/local and SRQ enabling are
accepted and do nothing; device_docmd and interrupt channels answer "operation not
supported". Errors use the specification's codes (4 invalid link, 15 I/O timeout: a read
with nothing to read).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import struct
from collections.abc import Callable
from dataclasses import dataclass, field

log = logging.getLogger(__name__)

CORE_PROG, CORE_VERS = 0x0607AF, 1
CREATE_LINK, WRITE, READ, READSTB, TRIGGER, CLEAR, REMOTE, LOCAL = 10, 11, 12, 13, 14, 15, 16, 17
LOCK, UNLOCK, ENABLE_SRQ, DOCMD, DESTROY_LINK = 18, 19, 20, 22, 23
END_FLAG = 0x08
REASON_END = 4
NO_ERROR, NOT_SUPPORTED, INVALID_LINK, IO_TIMEOUT = 0, 8, 4, 15
MAX_RECV = 1 << 20
MAX_RECORD = 1 << 22


class _Xdr:
    """Reads XDR items from a call's bytes."""

    def __init__(self, data: bytes) -> None:
        self.data, self.pos = data, 0

    def uint(self) -> int:
        (value,) = struct.unpack_from(">I", self.data, self.pos)
        self.pos += 4
        return int(value)

    def opaque(self) -> bytes:
        size = self.uint()
        value = self.data[self.pos:self.pos + size]
        self.pos += (size + 3) & ~3
        return value


def _opaque(data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + data + b"\0" * (-len(data) % 4)


def _ints(*values: int) -> bytes:
    return struct.pack(f">{len(values)}I", *(v & 0xFFFFFFFF for v in values))


@dataclass
class _Link:
    incoming: bytearray = field(default_factory=bytearray)
    outgoing: bytearray = field(default_factory=bytearray)


class Vxi11Server:
    """Serves `handle(message) -> response | None` and `stb(response_waiting) -> int`."""

    def __init__(
        self,
        handle: Callable[[str], str | None],
        stb: Callable[[bool], int],
        host: str = "127.0.0.1",
        port: int = 0,
    ) -> None:
        self.handle, self.stb = handle, stb
        self.host, self.port = host, port
        self._links: dict[int, _Link] = {}
        self._next_link = 1
        self._server: asyncio.Server | None = None

    async def start(self) -> None:
        self._server = await asyncio.start_server(self._serve, self.host, self.port,
                                                  reuse_address=True)
        self.port = self._server.sockets[0].getsockname()[1]

    def resource(self) -> str:
        return f"TCPIP::{self.host},{self.port}::inst0::INSTR"

    async def shutdown(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            server.close()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            while True:
                call = await _read_record(reader)
                if call is None:
                    break
                writer.write(_record(self.reply(call)))
                await writer.drain()
        except (ConnectionError, asyncio.IncompleteReadError, struct.error) as exc:
            log.debug("VXI-11 connection ended: %s", exc)
        finally:
            writer.close()
            with contextlib.suppress(ConnectionError):
                await writer.wait_closed()

    def reply(self, call: bytes) -> bytes:
        """One RPC call -> its reply (accepted; PROG_UNAVAIL or PROC_UNAVAIL when not ours)."""
        x = _Xdr(call)
        xid, _kind, _rpcvers, prog, vers, proc = (x.uint() for _ in range(6))
        for _ in range(2):  # credentials, verifier
            x.uint()
            x.opaque()
        head = _ints(xid, 1, 0, 0, 0)  # REPLY, MSG_ACCEPTED, verifier AUTH_NONE (empty)
        if (prog, vers) != (CORE_PROG, CORE_VERS):
            return head + _ints(1)  # PROG_UNAVAIL
        if proc == 0:
            return head + _ints(0)
        body = self._procedure(proc, x)
        return head + (_ints(3) if body is None else _ints(0) + body)  # PROC_UNAVAIL

    def _procedure(self, proc: int, x: _Xdr) -> bytes | None:
        if proc == CREATE_LINK:
            x.uint(), x.uint(), x.uint()  # client id, lock device, lock timeout
            x.opaque()  # device name (inst0)
            number, self._next_link = self._next_link, self._next_link + 1
            self._links[number] = _Link()
            return _ints(NO_ERROR, number, 0, MAX_RECV)
        link_id = x.uint()
        link = self._links.get(link_id)
        if link is None:
            return _ints(INVALID_LINK) + (_opaque(b"") if proc == READ else b"")
        if proc == WRITE:
            return self._write(link, x)
        if proc == READ:
            return self._read(link, x)
        if proc == READSTB:
            return _ints(NO_ERROR, self.stb(bool(link.outgoing)))
        if proc == CLEAR:
            link.incoming.clear()
            link.outgoing.clear()
            return _ints(NO_ERROR)
        if proc == DESTROY_LINK:
            del self._links[link_id]
            return _ints(NO_ERROR)
        if proc in (TRIGGER, REMOTE, LOCAL, LOCK, UNLOCK, ENABLE_SRQ):
            return _ints(NO_ERROR)
        if proc == DOCMD:
            return _ints(NOT_SUPPORTED, 0) + _opaque(b"")
        return _ints(NOT_SUPPORTED)

    def _write(self, link: _Link, x: _Xdr) -> bytes:
        x.uint(), x.uint()  # io timeout, lock timeout
        flags = x.uint()
        data = x.opaque()
        link.incoming += data
        if flags & END_FLAG:
            message = link.incoming.decode("latin-1").rstrip("\r\n")
            link.incoming.clear()
            response = self.handle(message)
            if response is not None:
                link.outgoing += response.encode("latin-1") + b"\n"
        return _ints(NO_ERROR, len(data))

    def _read(self, link: _Link, x: _Xdr) -> bytes:
        size = x.uint()
        if not link.outgoing:
            return _ints(IO_TIMEOUT, 0) + _opaque(b"")
        chunk = bytes(link.outgoing[:size])
        del link.outgoing[:size]
        return _ints(NO_ERROR, 0 if link.outgoing else REASON_END) + _opaque(chunk)


async def _read_record(reader: asyncio.StreamReader) -> bytes | None:
    """One RPC record (its fragments joined); None at a clean end of the connection."""
    record = bytearray()
    while True:
        try:
            header = await reader.readexactly(4)
        except asyncio.IncompleteReadError as exc:
            if not exc.partial and not record:
                return None
            raise
        (mark,) = struct.unpack(">I", header)
        record += await reader.readexactly(mark & 0x7FFFFFFF)
        if len(record) > MAX_RECORD:
            raise ConnectionError("an RPC record beyond 4 MiB")
        if mark & 0x80000000:
            return bytes(record)


def _record(reply: bytes) -> bytes:
    return struct.pack(">I", 0x80000000 | len(reply)) + reply
