"""Judging a rate table's status and waiting for it to reach its commanded rate or come to
rest, on the station clock.

The same for every table family: a fault or an open interlock is an exception; a driver polls
its own status until the status says done and the feedback matches the command, so a stale
AT_RATE or IN_POSITION bit left from the previous motion never ends a new wait.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from common.clock import Clock
from drivers.errors import InstrumentError, InstrumentTimeout, InterlockOpen, TableFault
from drivers.protocols import TableStatus

log = logging.getLogger(__name__)

RATE_MATCH_DPS = 0.5  # feedback within this + RATE_MATCH_REL x |command| counts as at rate
RATE_MATCH_REL = 0.005
POSITION_MATCH_DEG = 0.05


class TableWaits:
    """Mixin of the table drivers: `check`, `wait_at_rate`, `wait_in_position`, `safe_state`,
    and the checks of a rate or move command's arguments.

    The driver provides `read_status()`, `fault_text(code)`, `disable()`, `_demand_stop()`,
    `_clock`, `_poll_s` and the last commands `_rate_cmd_dps` / `_pos_cmd_deg` (None: no
    command to match)."""

    _clock: Clock
    _poll_s: float
    _rate_cmd_dps: float | None
    _pos_cmd_deg: float | None

    def read_status(self) -> TableStatus:
        raise NotImplementedError

    def fault_text(self, code: int) -> str:
        """What the controller's fault `code` means, in words an operator can act on."""
        raise NotImplementedError

    def disable(self) -> None:
        raise NotImplementedError

    def _demand_stop(self) -> None:
        """Command the moving table to come to rest (rate 0, or the drive's halt)."""
        raise NotImplementedError

    def safe_state(self, timeout_s: float = 30.0) -> None:
        """Bring a moving table to rest, wait for it, then disable the drive."""
        status = self.read_status()
        if status.enabled and not status.fault and status.moving:
            self._demand_stop()
            try:
                # even after an abort: the drive is disabled at rest, never while it turns
                # (on a lockstep bench no time passes but the station's own waits)
                self._wait(lambda s: not s.moving, timeout_s, "stop", through_abort=True)
            except InstrumentError as exc:  # a fault stops the table anyway
                log.warning("while stopping the rate table: %s", exc)
        self.disable()

    def _rate_command(
        self, rate_dps: float, accel_dps2: float | None, max_rate_dps: float
    ) -> None:
        """Check a rate command's arguments (ValueError) and take it as the command to match."""
        if not abs(rate_dps) <= max_rate_dps:
            raise ValueError(
                f"rate {rate_dps} deg/s is beyond the table's limit of {max_rate_dps} deg/s"
            )
        if accel_dps2 is not None and not accel_dps2 > 0:
            raise ValueError(f"acceleration must be positive, got {accel_dps2} deg/s^2")
        self._rate_cmd_dps = float(rate_dps)
        self._pos_cmd_deg = None

    @staticmethod
    def _check_move(accel_dps2: float | None, move_time_s: float | None) -> None:
        """ValueError unless a move gives at most one of a positive acceleration or time."""
        if accel_dps2 is not None and move_time_s is not None:
            raise ValueError("give move_to either accel_dps2 or move_time_s, not both")
        if accel_dps2 is not None and not accel_dps2 > 0:
            raise ValueError(f"acceleration must be positive, got {accel_dps2} deg/s^2")
        if move_time_s is not None and not move_time_s > 0:
            raise ValueError(f"move time must be positive, got {move_time_s} s")

    def _move_command(self, angle_deg: float) -> None:
        """Take a move to `angle_deg` as the command to match."""
        self._pos_cmd_deg = float(angle_deg)
        self._rate_cmd_dps = None

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
        self, done: Callable[[TableStatus], bool], timeout_s: float, what: str,
        *, through_abort: bool = False,
    ) -> TableStatus:
        deadline = self._clock.now_s() + timeout_s
        while True:
            status = self.check()
            interrupted = getattr(self._clock, "interrupted", False) and not through_abort
            if done(status) or interrupted:
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
