"""Push events to every open page (server-sent events).

Publishers may run on any thread (the engine runs in its own); each subscriber is an
asyncio queue drained by one SSE response on the server's event loop. A page that falls too
far behind is dropped: its EventSource reconnects and starts again from a fresh snapshot.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import threading
from collections.abc import AsyncIterator, Callable
from typing import Any

log = logging.getLogger(__name__)

_QUEUE_LIMIT = 500
_KEEPALIVE_S = 15.0


class Hub:
    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._subscribers: list[tuple[asyncio.AbstractEventLoop, asyncio.Queue[str | None]]] = []

    @property
    def subscriber_count(self) -> int:
        with self._lock:
            return len(self._subscribers)

    def publish(self, event: dict[str, Any]) -> None:
        """Send `event` to every subscriber; safe from any thread."""
        message = format_sse(event)
        with self._lock:
            targets = list(self._subscribers)
        for loop, queue in targets:
            try:
                loop.call_soon_threadsafe(self._offer, loop, queue, message)
            except RuntimeError:  # loop closed: the page is gone
                self._remove(queue)

    def close(self) -> None:
        """End every page's stream (before the server stops, so it need not wait for them)."""
        with self._lock:
            targets, self._subscribers = list(self._subscribers), []
        for loop, queue in targets:
            with contextlib.suppress(RuntimeError, asyncio.QueueFull):
                loop.call_soon_threadsafe(queue.put_nowait, None)

    def _offer(
        self, loop: asyncio.AbstractEventLoop, queue: asyncio.Queue[str | None], message: str
    ) -> None:
        try:
            queue.put_nowait(message)
        except asyncio.QueueFull:
            log.warning("a page fell behind the live updates; it will reconnect")
            self._remove(queue)
            queue.get_nowait()
            queue.put_nowait(None)  # ends that page's stream

    def _remove(self, queue: asyncio.Queue[str | None]) -> None:
        with self._lock:
            self._subscribers = [(lp, q) for lp, q in self._subscribers if q is not queue]

    async def stream(self, snapshot: Callable[[], dict[str, Any]]) -> AsyncIterator[str]:
        """One page's stream: the snapshot first (so a reload shows the run), then events."""
        queue: asyncio.Queue[str | None] = asyncio.Queue(maxsize=_QUEUE_LIMIT)
        loop = asyncio.get_running_loop()
        with self._lock:
            self._subscribers.append((loop, queue))
        try:
            # Subscribed before the snapshot is taken, so no event falls between the two.
            yield "retry: 1000\n" + format_sse(snapshot())
            while True:
                try:
                    message = await asyncio.wait_for(queue.get(), timeout=_KEEPALIVE_S)
                except TimeoutError:
                    yield ": keep-alive\n\n"
                    continue
                if message is None:
                    return
                yield message
        finally:
            self._remove(queue)


def format_sse(event: dict[str, Any]) -> str:
    """One SSE message carrying `event` as JSON in the default "message" channel."""
    try:
        text = json.dumps(event, separators=(",", ":"), allow_nan=False)
    except ValueError:  # NaN or infinity somewhere: the page's JSON.parse would refuse it
        text = json.dumps(_finite(event), separators=(",", ":"))
    return f"data: {text}\n\n"


def _finite(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value
