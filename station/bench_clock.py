"""The station's clock for the bench it runs on: real time, a scaled simulated bench, or a
simulated bench in lockstep (its world moves only when the station waits)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Protocol

from common.clock import LockstepClock, ScaledClock
from drivers.errors import ConnectionLost, InstrumentTimeout


class BenchTiming(Protocol):
    """What the clock needs to know of the bench (station.endpoints.Endpoints has it)."""

    @property
    def speed(self) -> float: ...

    @property
    def lockstep(self) -> bool: ...

    @property
    def control(self) -> str: ...


def station_clock(
    endpoints: BenchTiming | None, closers: list[Callable[[], None]], reply_s: float = 10.0
) -> ScaledClock:
    """Real time (no bench endpoints), the bench's speed, or lockstep through its control
    channel (a connection of its own, closed by `closers`; a bench that does not answer an
    advance within `reply_s` wall seconds is an instrument timeout)."""
    if endpoints is None:
        return ScaledClock(1.0)
    if not endpoints.lockstep:
        return ScaledClock(endpoints.speed)
    # the simulated bench: loaded only when asked for
    from drivers.sim.control_client import ControlClient, ControlError, ControlTimeout

    client = ControlClient(endpoints.control, timeout_s=reply_s)
    closers.append(client.close)

    def advance(t_s: float) -> Mapping[str, Any]:
        # the bench's clock is an instrument of the run: a bench that stops answering is an
        # instrument fault (ERROR, the safe-state pass, the reason in words), not a bug
        try:
            reply = client.request("advance", to_s=t_s)
        except ControlTimeout as exc:
            raise InstrumentTimeout(
                f"{exc}: the simulated bench's process is stopped or frozen; end it and start "
                "the bench again", instrument="simulated bench") from None
        except ControlError as exc:
            raise ConnectionLost(f"{exc}: the simulated bench has gone; start it again",
                                 instrument="simulated bench") from None
        return reply if isinstance(reply, Mapping) else {}

    clock = LockstepClock(advance)
    clock.start_at(client.world_time_s())
    return clock
