"""Judging a rate table's status and waiting for it to reach its commanded rate or come to
rest, on the station clock.

The same for every table family: a fault or an open interlock is an exception; a driver polls
its own status until the status says done and the feedback matches the command, so a stale
AT_RATE or IN_POSITION bit left from the previous motion never ends a new wait.
"""

from __future__ import annotations

from collections.abc import Callable

from drivers.clock import Clock
from drivers.errors import InstrumentTimeout, InterlockOpen, TableFault
from drivers.protocols import TableStatus

RATE_MATCH_DPS = 0.5  # feedback within this + RATE_MATCH_REL x |command| counts as at rate
RATE_MATCH_REL = 0.005
POSITION_MATCH_DEG = 0.05


class TableWaits:
    """Mixin of the table drivers: `check`, `wait_at_rate` and `wait_in_position`.

    The driver provides `read_status()`, `fault_text(code)`, `_clock`, `_poll_s` and the last
    commands `_rate_cmd_dps` / `_pos_cmd_deg` (None: no command to match)."""

    _clock: Clock
    _poll_s: float
    _rate_cmd_dps: float | None
    _pos_cmd_deg: float | None

    def read_status(self) -> TableStatus:
        raise NotImplementedError

    def fault_text(self, code: int) -> str:
        """What the controller's fault `code` means, in words an operator can act on."""
        raise NotImplementedError

    def check(self, status: TableStatus | None = None) -> TableStatus:
        """Raise InterlockOpen or TableFault if the table reports either; else the status."""
        status = status or self.read_status()
        if status.interlock_open:
            raise InterlockOpen(
                "the rate table's safety interlock is open (door or guard): close it, then "
                "reset the fault and enable the table again",
                fault_code=status.fault_code,
                instrument="rate table",
            )
        if status.fault:
            raise TableFault(
                f"rate table fault {status.fault_code}: {self.fault_text(status.fault_code)}; "
                "the table stopped and is disabled",
                fault_code=status.fault_code,
                instrument="rate table",
            )
        return status

    def _wait(
        self, done: Callable[[TableStatus], bool], timeout_s: float, what: str
    ) -> TableStatus:
        deadline = self._clock.now_s() + timeout_s
        while True:
            status = self.check()
            if done(status) or getattr(self._clock, "interrupted", False):
                # interrupted: the run was asked to stop (an abort, a signal); its next check
                # ends the step, and the safe-state pass stops the table, not the end of a move
                return status
            if self._clock.now_s() >= deadline:
                raise InstrumentTimeout(
                    f"the rate table did not {what} within {timeout_s:g} s (rate "
                    f"{status.rate_dps:.3f} deg/s, position {status.position_deg:.3f} deg, "
                    f"status {status}): check the load and the acceleration limit, or "
                    "lengthen the timeout",
                    instrument="rate table",
                )
            self._clock.sleep_s(self._poll_s)

    def wait_at_rate(self, timeout_s: float) -> TableStatus:
        cmd = self._rate_cmd_dps

        def done(s: TableStatus) -> bool:
            tolerance_dps = RATE_MATCH_DPS + RATE_MATCH_REL * abs(cmd or 0.0)
            near = cmd is None or abs(s.rate_dps - cmd) <= tolerance_dps
            return s.at_rate and near

        return self._wait(done, timeout_s, f"reach {cmd} deg/s")

    def wait_in_position(self, timeout_s: float) -> TableStatus:
        cmd = self._pos_cmd_deg

        def done(s: TableStatus) -> bool:
            near = cmd is None or abs(s.position_deg - cmd) <= POSITION_MATCH_DEG
            return s.in_position and near

        return self._wait(done, timeout_s, f"come to rest at {cmd} deg")
