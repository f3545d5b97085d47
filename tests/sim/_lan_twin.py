"""A world and one LAN twin on an asyncio loop in a background thread, so blocking drivers
(pyvisa) can talk to it from the test thread; `serve_forever` runs one in a child process."""

from __future__ import annotations

import asyncio
import sys
import threading
from collections.abc import Callable, Coroutine
from concurrent.futures import Future
from typing import Any, TypeVar

from drivers.sim.config import SimConfig
from drivers.sim.scpi_lan_twins import LAN_SUPPLY_TWINS
from drivers.sim.world import World

T = TypeVar("T")
TWINS = LAN_SUPPLY_TWINS
ONE_PART: dict[str, Any] = {"parts": [{"socket": 1, "serial": "SIM-S001"}]}


class TwinInThread:
    def __init__(self, family: str, channel: int = 1, config: dict[str, Any] | None = None,
                 speed: float = 100.0) -> None:
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self._thread.start()
        self.world = World(SimConfig.model_validate(config or ONE_PART), speed)
        self.twin = TWINS[family](self.world, channel=channel)
        self.run(self.twin.start())

    def run(self, coro: Coroutine[Any, Any, T]) -> T:
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(10)

    def call(self, fn: Callable[[], T]) -> T:
        """Run `fn` on the loop's thread (the world is not thread-safe)."""
        done: Future[T] = Future()

        def job() -> None:
            try:
                done.set_result(fn())
            except BaseException as exc:  # handed back to the caller
                done.set_exception(exc)

        self.loop.call_soon_threadsafe(job)
        return done.result(10)

    def truth(self) -> dict[str, Any]:
        def read() -> dict[str, Any]:
            self.world.advance()
            return self.world.supply.truth()

        return self.call(read)

    def close(self) -> None:
        self.run(self.twin.shutdown())
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(5)
        self.loop.close()


async def _serve_forever(family: str) -> None:
    world = World(SimConfig.model_validate(ONE_PART), 100.0)
    twin = TWINS[family](world)
    await twin.start()
    print(twin.endpoint(), flush=True)
    await asyncio.Event().wait()


if __name__ == "__main__":  # python -m tests.sim._lan_twin FAMILY: serve until killed
    asyncio.run(_serve_forever(sys.argv[1]))
