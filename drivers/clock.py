"""The station's clock.

The station never times a measurement with the wall clock. A real bench runs at speed 1; the
simulated bench runs its world at a published speed factor and the station's clock follows it,
so "wait 5 s" costs 5 s / speed of wall time. Sample times come from the fixture's own
timestamps, not from this clock; this clock only paces commands, dwells and timeouts.
"""

from __future__ import annotations

import threading
import time
from typing import Protocol


class Clock(Protocol):
    """Station time in seconds; advances `speed` times faster than the wall clock."""

    @property
    def speed(self) -> float: ...

    def now_s(self) -> float: ...

    def sleep_s(self, duration_s: float) -> None: ...

    def wall_timeout_s(self, duration_s: float) -> float: ...


class ScaledClock:
    """Station clock running at `speed` times real time (1.0 for real instruments).

    `sleep_s` can be cut short by `interrupt()`, so an operator abort ends a long dwell at once.
    """

    def __init__(self, speed: float = 1.0) -> None:
        if not speed > 0:
            raise ValueError(f"clock speed must be positive, got {speed!r}")
        self._speed = float(speed)
        self._t0 = time.monotonic()
        self._interrupt = threading.Event()

    @property
    def speed(self) -> float:
        return self._speed

    def now_s(self) -> float:
        return (time.monotonic() - self._t0) * self._speed

    def sleep_s(self, duration_s: float) -> None:
        if duration_s > 0:
            self._interrupt.wait(duration_s / self._speed)

    def wall_timeout_s(self, duration_s: float) -> float:
        """Wall-clock seconds that `duration_s` of station time takes."""
        return duration_s / self._speed

    def interrupt(self) -> None:
        """Wake every sleeper now and make later sleeps return at once (abort)."""
        self._interrupt.set()

    @property
    def interrupted(self) -> bool:
        return self._interrupt.is_set()
