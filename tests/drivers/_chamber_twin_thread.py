"""One twin on its own asyncio loop in a thread, over a fresh world (real loopback sockets)."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Awaitable, Callable
from typing import Any, Generic, Protocol, TypeVar

from drivers.sim.config import parse_sim_config
from drivers.sim.world import World


class Twin(Protocol):
    async def start(self) -> None: ...

    async def shutdown(self) -> None: ...

    def endpoint(self) -> str: ...


T = TypeVar("T", bound=Twin)
R = TypeVar("R")


class TwinThread(Generic[T]):
    """`with TwinThread(EspecP300Twin, speed=100) as tt:` -> tt.twin, tt.world, tt.endpoint."""

    def __init__(
        self, make: Callable[[World], T], config: dict[str, Any] | None = None, speed: float = 1.0
    ) -> None:
        self.world = World(parse_sim_config(config or {}), speed)
        self.twin = make(self.world)
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True)

    def __enter__(self) -> TwinThread[T]:
        self._thread.start()
        self.run(self.twin.start())
        return self

    def __exit__(self, *exc: object) -> None:
        self.run(self.twin.shutdown())
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(5)
        self._loop.close()

    @property
    def endpoint(self) -> str:
        return self.twin.endpoint()

    def run(self, coro: Awaitable[R], timeout_s: float = 10.0) -> R:
        """Run a coroutine on the twin's loop and return its result."""

        async def wrap() -> R:
            return await coro

        return asyncio.run_coroutine_threadsafe(wrap(), self._loop).result(timeout_s)

    def call(self, fn: Callable[[], R]) -> R:
        """Run `fn` on the twin's loop (world changes without racing a request)."""

        async def wrap() -> R:
            return fn()

        return self.run(wrap())

    def stick_chamber(self, report_fault: bool = True) -> None:
        """The world's chamber_stuck fault, as the bench's control channel sets it."""

        def stick() -> None:
            self.world.advance()
            self.world.chamber.stuck = True
            self.world.chamber.stuck_reports_fault = report_fault

        self.call(stick)
