"""The bench's control channel: JSON lines over TCP on loopback, one request -> one reply.

It stands in for the operator (load and unload parts), injects faults and reads the world's
truth, for tests and benchmarks only; the station never uses it. A request is
`{"cmd": NAME, ...params}`; the reply is `{"ok": true, "result": ...}` or
`{"ok": false, "error": "what went wrong and what to do"}`.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from collections.abc import Awaitable, Callable
from typing import Any

log = logging.getLogger(__name__)
Dispatcher = Callable[[dict[str, Any]], Awaitable[Any]]
MAX_REQUEST_BYTES = 1 << 20


class ControlRequestError(ValueError):
    """A control request that cannot be carried out; the message says why."""


class ControlServer:
    def __init__(self, dispatch: Dispatcher, host: str = "127.0.0.1", port: int = 0) -> None:
        self._dispatch = dispatch
        self.host = host
        self.port = port
        self._server: asyncio.base_events.Server | None = None
        self._clients: set[asyncio.StreamWriter] = set()

    async def start(self) -> None:
        self._server = await asyncio.start_server(
            self._client, self.host, self.port, limit=MAX_REQUEST_BYTES
        )
        self.port = self._server.sockets[0].getsockname()[1]

    @property
    def endpoint(self) -> str:
        return f"{self.host}:{self.port}"

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._clients.add(writer)
        try:
            while True:
                try:
                    line = await reader.readline()
                except (ConnectionError, ValueError):
                    break
                if not line:
                    break
                reply = await self._answer(line)
                writer.write(json.dumps(reply).encode() + b"\n")
                await writer.drain()
        except ConnectionError:
            pass
        finally:
            self._clients.discard(writer)
            writer.close()

    async def _answer(self, line: bytes) -> dict[str, Any]:
        try:
            request = json.loads(line.decode("utf-8"))
        except UnicodeDecodeError as exc:
            return {"ok": False, "error": f"not UTF-8 text (byte {exc.start}); send JSON"}
        except (ValueError, RecursionError) as exc:  # JSONDecodeError, or nested too deep
            what = "nested too deep" if isinstance(exc, RecursionError) else str(exc)
            return {"ok": False, "error": f"not JSON ({what}); send one JSON object per line"}
        if not isinstance(request, dict) or not isinstance(request.get("cmd"), str):
            return {"ok": False, "error": 'send an object with a "cmd" string'}
        try:
            return {"ok": True, "result": await self._dispatch(request)}
        except (ControlRequestError, KeyError, ValueError, TypeError) as exc:
            return {"ok": False, "error": str(exc).strip("'\"")}
        except Exception as exc:  # report, keep the bench alive
            log.exception("control request %r failed", request)
            return {"ok": False, "error": f"internal error: {exc!r}"}

    async def shutdown(self) -> None:
        if self._server is not None:
            self._server.close()
            for w in list(self._clients):
                w.close()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._server.wait_closed(), 2.0)
            self._server = None
