"""The progress event stream: what the CLI shows and the browser UI subscribes to.

The engine publishes `ProgressEvent`s on a `ProgressBus`; subscribers are plain callables
(called in the engine's thread, so they must be quick) or queues (`subscribe_queue`, for a
UI thread or an asyncio bridge). A subscriber that raises is dropped, never the run.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ProgressEvent:
    kind: str  # "step" | "progress" | "part" | "log" | "finished"
    step: str = ""
    condition: str = ""
    # what a long step is doing now ("heating", "cooling", ...: the step's own phase names),
    # "" for a step that names none; a change of phase is published as a "step" event
    phase: str = ""
    fraction: float = 0.0  # of the whole procedure, 0..1 (planned station time)
    station_time_s: float = 0.0
    remaining_s: float | None = None  # station seconds, estimated
    message: str = ""
    sockets: dict[int, str] = field(default_factory=dict)  # socket -> state or verdict
    # a reorientation prompt's face that must point up ("+x" .. "-z"); None otherwise
    orientation: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


Subscriber = Callable[[ProgressEvent], None]


class ProgressBus:
    """Fan-out of progress events; thread-safe; keeps the last event for late subscribers."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._subscribers: list[Subscriber] = []
        self.last: ProgressEvent | None = None

    def subscribe(self, fn: Subscriber) -> Callable[[], None]:
        """Add a subscriber; returns a function that removes it."""
        with self._lock:
            self._subscribers.append(fn)

        def unsubscribe() -> None:
            with self._lock:
                if fn in self._subscribers:
                    self._subscribers.remove(fn)

        return unsubscribe

    def subscribe_queue(
        self, maxsize: int = 1000
    ) -> tuple[queue.Queue[ProgressEvent], Callable[[], None]]:
        """Events into a queue (oldest dropped when full); returns (queue, unsubscribe)."""
        q: queue.Queue[ProgressEvent] = queue.Queue(maxsize=maxsize)

        def put(event: ProgressEvent) -> None:
            while True:
                try:
                    q.put_nowait(event)
                    return
                except queue.Full:
                    with contextlib.suppress(queue.Empty):
                        q.get_nowait()

        return q, self.subscribe(put)

    def publish(self, event: ProgressEvent) -> None:
        with self._lock:
            self.last = event
            subscribers = list(self._subscribers)
        for fn in subscribers:
            try:
                fn(event)
            except Exception:  # a broken display must not stop a calibration
                log.exception("progress subscriber failed; removing it")
                with self._lock:
                    if fn in self._subscribers:
                        self._subscribers.remove(fn)
