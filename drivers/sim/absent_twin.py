"""The twin of an instrument the bench does not have (sim config `instruments.rate_table:
none`): nothing listens, its endpoint is '' in the state file, and the fault calls the bench
makes on every twin do nothing. The world still holds the table's model, at rest at 0 deg,
so a fixture turned by hand (drivers/sim/hand.py) is the only motion the parts see."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


class AbsentTwin:
    def __init__(self, world: Any, host: str = "127.0.0.1", port: int = 0) -> None:
        self.world = world
        self.delay_s = 0.0
        self.dropped = False
        self.requests = 0
        self.before_write: Callable[[float], None] | None = None

    async def start(self) -> None:
        return None

    def endpoint(self) -> str:
        return ""

    async def drop(self) -> None:
        return None

    async def restore(self) -> None:
        return None

    async def shutdown(self) -> None:
        return None
