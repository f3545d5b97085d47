"""The run's watchdog: the shared instruments polled every `period_s` of station time,
whatever the step is doing.

`RunContext.check` (which every wait of every step goes through) calls `Watchdog.poll`; when
the period has passed it asks each instrument that implements `drivers.protocols.Watched`
(`watchdog_check()`: the table's e-stop, fault, interlock and heartbeat; the chamber's FAULT
state) and lets its typed `InstrumentError` end the run. A table without `watchdog_check` is
judged from `read_status()`. An instrument that cannot be reached at all raises there too, so
a lost link is found within one period, not at the next step that needs it.
"""

from __future__ import annotations

import logging
from typing import Any

from common.clock import Clock
from drivers.errors import InterlockOpen, TableFault
from drivers.protocols import Watched

log = logging.getLogger(__name__)

# station seconds between polls: with the 1 s slices of RunContext.sleep, a poll every 2 s
WATCHDOG_PERIOD_S = 1.5
# ... but never more often than this in wall time: on a simulated bench above 100x, station
# seconds are milliseconds and polls would crowd the bench's one event loop (at 200x the
# watchdog then polls every 4 station s; a real bench runs at 1x)
WATCHDOG_MIN_WALL_S = 0.02


class Watchdog:
    """Polls `instruments` (name -> driver) at most every `period_s` station seconds."""

    def __init__(
        self, instruments: dict[str, Any], clock: Clock, period_s: float = WATCHDOG_PERIOD_S
    ) -> None:
        self.instruments = {k: v for k, v in instruments.items() if v is not None}
        self.clock = clock
        self.period_s = period_s
        self._last_s: float | None = None
        self.polls = 0

    @property
    def effective_period_s(self) -> float:
        return max(self.period_s, WATCHDOG_MIN_WALL_S * self.clock.speed)

    def due(self) -> bool:
        return self._last_s is None or self.clock.now_s() - self._last_s >= self.effective_period_s

    def poll(self, force: bool = False) -> None:
        """Check every instrument if the period has passed; raises its InstrumentError."""
        if not (force or self.due()):
            return
        self._last_s = self.clock.now_s()
        self.polls += 1
        for name, driver in self.instruments.items():
            if isinstance(driver, Watched):
                driver.watchdog_check()
            elif name == "rate_table" and callable(getattr(driver, "read_status", None)):
                _check_table_status(driver)


def _check_table_status(table: Any) -> None:
    status = table.read_status()
    if status.interlock_open:
        raise InterlockOpen(
            "the rate table's safety interlock is open (door or guard): close it, then reset "
            "the fault and rerun",
            fault_code=status.fault_code,
            instrument="rate table",
        )
    if status.fault:
        raise TableFault(
            f"the rate table reports fault {status.fault_code}: release any e-stop, reset the "
            "fault, then rerun",
            fault_code=status.fault_code,
            instrument="rate table",
        )
