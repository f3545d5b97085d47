"""Run one twin on its own asyncio loop in a thread, over a fresh World (tests only)."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Coroutine
from typing import Any

from drivers.sim.config import SimConfig
from drivers.sim.world import World


class TwinThread:
    """`make(world)` builds the twin; `start()` serves it on 127.0.0.1, port 0."""

    def __init__(
        self, make: Callable[[World], Any], *, speed: float = 100.0,
        config: dict[str, Any] | None = None,
    ) -> None:
        self.world = World(SimConfig.model_validate(config or {}), speed=speed)
        self.twin = make(self.world)
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self.loop.run_forever, daemon=True)

    def run(self, coro: Coroutine[Any, Any, Any], timeout_s: float = 10.0) -> Any:
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout_s)

    def call(self, fn: Callable[[], Any]) -> Any:
        """Run `fn` on the twin's loop (world changes must not race a request)."""

        async def wrapped() -> Any:
            return fn()

        return self.run(wrapped())

    def start(self) -> TwinThread:
        self._thread.start()
        self.run(self.twin.start())
        return self

    def close(self) -> None:
        self.run(self.twin.shutdown())
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(5)
        self.loop.close()

    def __enter__(self) -> TwinThread:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
