"""The station's clock.

The station never times a measurement with the wall clock. A real bench runs at speed 1; the
simulated bench runs its world at a published speed factor and the station's clock follows it,
so "wait 5 s" costs 5 s / speed of wall time. Sample times come from the fixture's own
timestamps, not from this clock; this clock only paces commands, dwells and timeouts.

In lockstep (`LockstepClock`, the simulated bench's default) there is no speed: the world
advances only while the station waits, by exactly the wait, so station time is physics time and
machine load changes only how long a run takes in wall time.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping
from typing import Any, Protocol


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

    # True when every sample taken up to now_s() is already in when a sleep returns
    lockstep = False
    # a long wait may be cut into slices this long (station s) to check on the run between
    check_every_s = 0.0

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


Advance = Callable[[float], Mapping[str, Any]]
Waiter = Callable[[float, Mapping[str, Any]], None]
# longest station step per bench request: the samples of one step (125 kB a socket at 1 kHz)
# fit the fixture's FIFO, and the die's 5 min lag is linear over it
LOCKSTEP_STEP_S = 5.0


class LockstepClock(ScaledClock):
    """Station time that moves only while the station waits (the simulated bench in lockstep).

    `sleep_s(d)` asks the bench to advance its world by `d` (in steps of at most `max_step_s`,
    through `advance(t_s)`, which returns the bench's reply), then calls every waiter with the
    new time and that reply, so the samples of the interval are in before the caller goes on.
    Station time is physics time: machine load only makes a run take longer in wall time.
    `speed` is 1: wall timeouts (an instrument's reply) are as long as on a real bench.
    After `interrupt()` (abort) a sleep still moves station time, in one step, so every
    deadline loop ends.
    """

    lockstep = True
    check_every_s = LOCKSTEP_STEP_S  # each slice costs a bench round trip, not wall time

    def __init__(self, advance: Advance, max_step_s: float = LOCKSTEP_STEP_S) -> None:
        super().__init__(1.0)
        if not max_step_s > 0:
            raise ValueError(f"lockstep step must be positive, got {max_step_s!r}")
        self._advance = advance
        self.max_step_s = float(max_step_s)
        self._now_s = 0.0
        self._step_lock = threading.Lock()
        self._waiters: list[Waiter] = []

    def now_s(self) -> float:
        return self._now_s

    def start_at(self, t_s: float) -> None:
        """Take the bench's current world time as station time (once, before the run)."""
        with self._step_lock:
            self._now_s = max(self._now_s, float(t_s))

    def sleep_s(self, duration_s: float) -> None:
        if not duration_s > 0:
            return
        end_s = self._now_s + duration_s
        while True:
            with self._step_lock:
                if self._now_s >= end_s - 1e-9:
                    return
                # after an abort the wait still passes (a driver's deadline loop must end),
                # in one step: nobody measures any more
                step_s = end_s - self._now_s if self.interrupted else self.max_step_s
                target_s = min(end_s, self._now_s + step_s)
                # station time moves first: a sample read while the bench answers is never
                # later than the station clock (the streams' offset estimate relies on it)
                self._now_s = target_s
                reply = self._advance(target_s)
                waiters = list(self._waiters)
            for waiter in waiters:
                waiter(target_s, reply)

    def wall_timeout_s(self, duration_s: float) -> float:
        return duration_s

    def add_waiter(self, waiter: Waiter) -> None:
        """Call `waiter(t_s, reply)` after every step (the acquisition catches up there)."""
        with self._step_lock:
            self._waiters.append(waiter)

    def remove_waiter(self, waiter: Waiter) -> None:
        with self._step_lock:
            if waiter in self._waiters:
                self._waiters.remove(waiter)
