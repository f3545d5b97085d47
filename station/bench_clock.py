"""The station's clock for the bench it runs on: real time, a scaled simulated bench, or a
simulated bench in lockstep (its world moves only when the station waits)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Protocol

from common.clock import LockstepClock, ScaledClock


class BenchTiming(Protocol):
    """What the clock needs to know of the bench (station.endpoints.Endpoints has it)."""

    @property
    def speed(self) -> float: ...

    @property
    def lockstep(self) -> bool: ...

    @property
    def control(self) -> str: ...


def station_clock(
    endpoints: BenchTiming | None, closers: list[Callable[[], None]]
) -> ScaledClock:
    """Real time (no bench endpoints), the bench's speed, or lockstep through its control
    channel (a connection of its own, closed by `closers`)."""
    if endpoints is None:
        return ScaledClock(1.0)
    if not endpoints.lockstep:
        return ScaledClock(endpoints.speed)
    # the simulated bench: loaded only when asked for
    from drivers.sim.control_client import ControlClient

    client = ControlClient(endpoints.control)
    closers.append(client.close)

    def advance(t_s: float) -> Mapping[str, Any]:
        reply = client.request("advance", to_s=t_s)
        return reply if isinstance(reply, Mapping) else {}

    clock = LockstepClock(advance)
    clock.start_at(client.world_time_s())
    return clock
