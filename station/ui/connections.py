"""Caps on the operator screen's connections, so a flood never blocks START or ABORT.

uvicorn keeps every accepted connection until the client closes it, and one that never sends
a request has no timeout at all: a thousand idle connections used to hold a thousand
descriptors, and the station's next instrument link failed for want of one. Here each
connection is admitted by a `ConnectionLimiter` on the server's event loop:

- at most `per_client` connections from one address and `total` in all; a new connection
  over either cap takes the place of the oldest *idle* connection (no request under way:
  never sent one, or between keep-alive requests) of that address, else of any address, so
  a flood of idle connections gives way to a screen that sends a request; with nothing idle
  to close, the new connection is closed at once;
- a connection that has not sent a whole request header `first_request_s` after connecting
  is closed (uvicorn's keep-alive timeout starts only after a first response).

Requests under way (a START, an ABORT, a screen's event stream) are never closed for
another connection. Every loopback client shares one address, the station's own screen too:
the eviction, not the per-address cap alone, is what lets it in.
"""

from __future__ import annotations

import asyncio
import logging
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

from uvicorn.protocols.http.auto import AutoHTTPProtocol

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ConnectionLimits:
    """station.yaml `ui.max_connections`, `ui.max_connections_per_client`."""

    total: int = 256
    per_client: int = 64
    first_request_s: float = 10.0


def _idle(protocol: Any) -> bool:
    """No request under way: none begun (headers incomplete) or the last one answered."""
    cycle = getattr(protocol, "cycle", None)
    return cycle is None or bool(getattr(cycle, "response_complete", False))


class ConnectionLimiter:
    """The open connections, oldest first; used only on the server's event loop."""

    def __init__(self, limits: ConnectionLimits) -> None:
        self.limits = limits
        self._open: OrderedDict[Any, str] = OrderedDict()  # protocol -> client address
        self._per_client: dict[str, int] = {}
        self.refused = 0
        self.evicted = 0

    @property
    def count(self) -> int:
        return len(self._open)

    def admit(self, protocol: Any, client: str) -> bool:
        """Make room for a new connection from `client` if the caps need it; False when
        there is none (every connection over the cap has a request under way)."""
        if self._per_client.get(client, 0) >= self.limits.per_client and not self._evict(client):
            self.refused += 1
            return False
        if len(self._open) >= self.limits.total and not (
            self._evict(client) or self._evict(None)
        ):
            self.refused += 1
            return False
        self._open[protocol] = client
        self._per_client[client] = self._per_client.get(client, 0) + 1
        return True

    def release(self, protocol: Any) -> None:
        client = self._open.pop(protocol, None)
        if client is None:
            return
        left = self._per_client[client] - 1
        if left:
            self._per_client[client] = left
        else:
            del self._per_client[client]

    def _evict(self, client: str | None) -> bool:
        """Close the oldest idle connection (of `client`, or of anyone); False if none."""
        for protocol, who in self._open.items():
            if (client is None or who == client) and _idle(protocol):
                self.release(protocol)  # now: its connection_lost comes on a later loop turn
                protocol.transport.close()
                self.evicted += 1
                return True
        return False


def capped_protocol(limits: ConnectionLimits) -> type[asyncio.Protocol]:
    """uvicorn's HTTP protocol class with `limits` applied (uvicorn.Config(http=...)): one
    limiter per class, so per server."""
    limiter = ConnectionLimiter(limits)

    class CappedHTTPProtocol(AutoHTTPProtocol):  # type: ignore[misc, valid-type]
        connection_limiter = limiter

        def connection_made(self, transport: asyncio.Transport) -> None:
            peer = transport.get_extra_info("peername")
            client = str(peer[0]) if isinstance(peer, tuple) and peer else "unknown"
            if not limiter.admit(self, client):
                self._capped_out = True
                transport.abort()  # never handed to uvicorn: nothing of it to clean up
                return
            self._capped_out = False
            super().connection_made(transport)
            asyncio.get_running_loop().call_later(limits.first_request_s, self._first_request_due)

        def connection_lost(self, exc: Exception | None) -> None:
            if self._capped_out:
                return
            limiter.release(self)
            super().connection_lost(exc)

        def _first_request_due(self) -> None:
            # no request begun by now; after one, uvicorn's keep-alive timeout takes over
            if getattr(self, "cycle", None) is None and not self.transport.is_closing():
                limiter.release(self)
                self.transport.close()

    return CappedHTTPProtocol
