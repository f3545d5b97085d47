"""The Chamber protocol's behaviour shared by chamber drivers whose controller has no ramp rate.

A Watlow F4T loop (as ESPEC's chambers configure it) and an ESPEC P-300 in constant mode step
to a new setpoint as fast as the chamber can: neither takes a ramp rate over its remote
interface. `RampedChamber` does the ramp in the driver instead: `set_setpoint` with a ramp
rate set starts a ramp from the air temperature, and every later call to the driver (the
station reads the chamber at every stability check) writes the ramped setpoint for the
station time it is called at, in steps of at least `RAMP_STEP_C`. Between calls the controller
holds the last ramped value, so the ramp is a staircase as fine as the station polls.
`read_setpoint` answers the target, not the ramped value.

A subclass provides the wire primitives (`_read_limits`, `_write_setpoint`, `_read_wire_setpoint`,
`_read_pv`, `_start`, `_standby`, `_running`, `_alarms`) plus `identify`, `close` and
`reconnect`; the safe-state readback (`check_safe`) is shared.
"""

from __future__ import annotations

import logging
from abc import ABC, abstractmethod

from common.clock import Clock, ScaledClock
from drivers.errors import (
    ChamberAlarm,
    ChamberSetpointNotReached,
    InstrumentError,
    SetpointOutOfRange,
)
from drivers.protocols import InstrumentIdentity, SafeReadback

log = logging.getLogger(__name__)

MAX_RAMP_C_PER_MIN = 1000.0
RAMP_STEP_C = 0.1  # smallest setpoint change the ramp writes (the controllers show tenths)
# how far the controller's setpoint may be from the safe one and still read back as it: the
# P-300 takes tenths, the F4T a float (in F when so configured), so half a tenth and a hair
SAFE_SETPOINT_TOLERANCE_C = 0.06


class SetpointRamp:
    """A setpoint moving linearly from a start to a target at a rate, in station time."""

    def __init__(self) -> None:
        self.rate_c_per_min = 0.0
        self.target_c: float | None = None  # None: no ramp under way or waiting
        self.started = False  # False: waiting for the chamber to run
        self._start_c = 0.0
        self._start_s = 0.0

    @property
    def active(self) -> bool:
        return self.target_c is not None

    def hold(self, target_c: float) -> None:
        """A ramp to `target_c` that begins when the chamber runs."""
        self.target_c = target_c
        self.started = False

    def begin(self, from_c: float, target_c: float, now_s: float) -> None:
        self.target_c = target_c
        self.started = True
        self._start_c = from_c
        self._start_s = now_s

    def cancel(self) -> None:
        self.target_c = None
        self.started = False

    def value_at(self, now_s: float) -> float | None:
        """The ramped setpoint at `now_s` (None before it starts); the ramp ends once it
        reaches the target."""
        if self.target_c is None or not self.started:
            return None
        step_c = self.rate_c_per_min / 60.0 * max(0.0, now_s - self._start_s)
        delta_c = self.target_c - self._start_c
        if abs(delta_c) <= step_c:
            target = self.target_c
            self.cancel()
            return target
        return self._start_c + (step_c if delta_c > 0 else -step_c)


class RampedChamber(ABC):
    """`drivers.protocols.Chamber` over a subclass's wire primitives, ramping in the driver.

    Args:
        name: the instrument's name in messages.
        clock: the station clock (waits and the ramp run on it); `attach_clock` replaces it.
        poll_s: station seconds between polls while waiting for the setpoint.
    """

    def __init__(self, name: str, clock: Clock | None = None, *, poll_s: float = 1.0) -> None:
        self.name = name
        self._clock: Clock = clock or ScaledClock(1.0)
        self._poll_s = poll_s
        self._limits: tuple[float, float] | None = None
        self._ramp = SetpointRamp()
        self._written_c: float | None = None  # the last setpoint this driver wrote

    def attach_clock(self, clock: Clock) -> None:
        self._clock = clock

    # ------------------------------------------------------------ wire primitives

    @abstractmethod
    def identify(self) -> InstrumentIdentity: ...

    @abstractmethod
    def close(self) -> None: ...

    @abstractmethod
    def reconnect(self, timeout_s: float | None = None) -> None:
        """Drop the connection and open a new one, with a new reply timeout (wall s) if
        given: the safe-state pass's way through to a slow or re-plugged controller."""

    @abstractmethod
    def _read_limits(self) -> tuple[float, float]:
        """(low, high) setpoint limits, C."""

    @abstractmethod
    def _write_setpoint(self, temp_c: float) -> None:
        """Write the controller's setpoint; SetpointOutOfRange when it refuses the value."""

    @abstractmethod
    def _read_wire_setpoint(self) -> float: ...

    @abstractmethod
    def _read_pv(self) -> float: ...

    @abstractmethod
    def _start(self) -> None:
        """Control on at the setpoint (constant mode)."""

    @abstractmethod
    def _standby(self) -> None:
        """Control off (heater and refrigeration off, the controller still answers)."""

    @abstractmethod
    def _running(self) -> bool: ...

    @abstractmethod
    def _alarms(self) -> list[str]:
        """The controller's active alarms, one description each; empty when none."""

    def probe(self) -> str:
        """A cheap health check for the instrument lights: '' when the controller answers and
        reports no alarm, else its alarms. Raises an `InstrumentError` when unreachable."""
        return "; ".join(self._alarms())

    def watchdog_check(self) -> None:
        """Raise ChamberAlarm when the controller reports an alarm (the run's watchdog)."""
        alarms = self._alarms()
        if alarms:
            self._raise_on_alarm(self._read_pv(), self.read_setpoint(), alarms)

    def _raise_on_alarm(
        self, pv: float, setpoint: float, alarms: list[str] | None = None
    ) -> None:
        alarms = self._alarms() if alarms is None else alarms
        if alarms:
            raise ChamberAlarm(
                f"the chamber reports {'; '.join(alarms)} at {pv:g} C and cannot reach "
                f"{setpoint:g} C: check the chamber (compressor, heater, limit), clear the "
                "alarm at its panel, then rerun",
                instrument=self.name,
            )

    # ------------------------------------------------------------ setpoint and limits

    def setpoint_limits(self) -> tuple[float, float]:
        if self._limits is None:
            self._limits = self._read_limits()
        return self._limits

    def _check_limits(self, temp_c: float) -> None:
        low, high = self.setpoint_limits()
        if not low <= temp_c <= high:
            raise SetpointOutOfRange(
                f"chamber setpoint {temp_c:g} C is outside the controller's limits "
                f"[{low:g}, {high:g}] C: change the procedure's temperatures or the limits",
                instrument=self.name,
            )

    def _write(self, temp_c: float) -> None:
        try:
            self._write_setpoint(temp_c)
        except SetpointOutOfRange:
            self._limits = None  # the limits may have been changed at the controller
            self._ramp.cancel()
            raise
        self._written_c = temp_c

    def set_ramp_rate(self, c_per_min: float) -> None:
        """Ramp limit in C/min, done by this driver; 0 steps as fast as the chamber can."""
        if not 0 <= c_per_min <= MAX_RAMP_C_PER_MIN:
            raise ValueError(
                f"ramp rate must be 0..{MAX_RAMP_C_PER_MIN:g} C/min, got {c_per_min!r}"
            )
        self._ramp.rate_c_per_min = float(c_per_min)

    def set_setpoint(self, temp_c: float) -> None:
        self._check_limits(temp_c)
        ramping_from = self._written_c if self._ramp.started else None
        self._ramp.cancel()
        if self._ramp.rate_c_per_min > 0 and self._running():
            # a new target mid-ramp continues from the ramp's last step, else from the air
            start_c = ramping_from if ramping_from is not None else self._read_pv()
            self._ramp.begin(start_c, temp_c, self._clock.now_s())
            self._advance_ramp(force=True)
        elif self._ramp.rate_c_per_min > 0:
            self._ramp.hold(temp_c)  # the ramp starts from the air temperature at run()
        else:
            self._write(temp_c)

    def _advance_ramp(self, *, force: bool = False) -> None:
        target = self._ramp.target_c
        value = self._ramp.value_at(self._clock.now_s())
        if value is None:
            return
        last = self._written_c
        if force or value == target or last is None or abs(value - last) >= RAMP_STEP_C:
            self._write(round(value, 3))

    def read_setpoint(self) -> float:
        if self._ramp.target_c is not None:
            target = self._ramp.target_c
            self._advance_ramp()
            return target
        return self._read_wire_setpoint()

    def read_temperature(self) -> float:
        self._advance_ramp()
        return self._read_pv()

    # ------------------------------------------------------------ run/stop

    def run(self) -> None:
        if self._ramp.target_c is not None and not self._ramp.started:
            self._ramp.begin(self._read_pv(), self._ramp.target_c, self._clock.now_s())
            self._advance_ramp(force=True)
        self._start()

    def stop(self) -> None:
        self._standby()

    def is_running(self) -> bool:
        self._advance_ramp()
        return self._running()

    def wait_setpoint(self, band_c: float, timeout_s: float) -> float:
        if not band_c > 0:
            raise ValueError(f"band must be positive, got {band_c!r} C")
        setpoint = self.read_setpoint()
        if not self._running():
            raise InstrumentError(
                f"the chamber is stopped, so it will not reach {setpoint:g} C: call run() first",
                instrument=self.name,
            )
        deadline = self._clock.now_s() + timeout_s
        while True:
            pv = self.read_temperature()
            if abs(pv - setpoint) <= band_c:
                return pv
            self._raise_on_alarm(pv, setpoint)
            if self._clock.now_s() >= deadline:
                raise ChamberSetpointNotReached(
                    f"the chamber did not reach {setpoint:g} +/- {band_c:g} C within "
                    f"{timeout_s:g} s (now {pv:g} C): check the chamber door, the compressor "
                    "and the ramp rate, or lengthen the timeout",
                    instrument=self.name,
                )
            self._clock.sleep_s(self._poll_s)

    def safe_state(self, safe_temp_c: float = 25.0) -> None:
        """Head back to a safe temperature at once, still running so the air gets there."""
        self._ramp.cancel()
        low, high = self.setpoint_limits()
        self._write(min(max(safe_temp_c, low), high))
        self._start()

    def check_safe(self, safe_temp_c: float) -> SafeReadback:
        """Read back whether the controller holds the safe setpoint (within its limits): the
        setpoint on the wire, not a ramp's target, which only this driver knows."""
        low, high = self.setpoint_limits()
        target = min(max(safe_temp_c, low), high)
        setpoint = self._read_wire_setpoint()
        air = self._read_pv()
        running = "running" if self._running() else "stopped"
        detail = f"setpoint {setpoint:g} C (safe {target:g} C), air {air:g} C, {running}"
        return SafeReadback(abs(setpoint - target) <= SAFE_SETPOINT_TOLERANCE_C, detail)
