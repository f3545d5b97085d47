"""Thermal chamber controller over Modbus TCP, Watlow F4 style (map: drivers.chamber_map).

Temperatures are signed tenths of a degree C in 16-bit registers. A setpoint outside the
controller's limits is refused here before it is sent (and the controller's own refusal,
Modbus exception 3, maps to the same `SetpointOutOfRange`). `wait_setpoint` polls in station
time and gives up early when the controller reports it cannot reach the setpoint.
"""

from __future__ import annotations

import logging
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator

from common.address import check_host_port, split_host_port
from common.clock import Clock, ScaledClock
from drivers.chamber_map import DEVICE_ID, STRING_REGS, TENTHS, Reg, State
from drivers.errors import (
    ChamberFault,
    ChamberSetpointNotReached,
    InstrumentError,
    SetpointOutOfRange,
)
from drivers.modbus_link import (
    ModbusLink,
    ModbusRefused,
    i16_to_u16,
    read_identity,
    reopen_link,
    u16_to_i16,
)
from drivers.protocols import InstrumentIdentity, SafeReadback

log = logging.getLogger(__name__)

NAME = "thermal chamber"
MAX_RAMP_C_PER_MIN = 0xFFFF / TENTHS


def _to_tenths(temp_c: float) -> int:
    return i16_to_u16(int(round(temp_c * TENTHS)))


def _from_tenths(reg: int) -> float:
    return u16_to_i16(reg) / TENTHS


class ModbusChamber:
    """`drivers.protocols.Chamber` over Modbus TCP.

    Args:
        link: an open or openable `ModbusLink` to the controller.
        clock: the station clock; `wait_setpoint` polls and times out on it.
        poll_s: station seconds between polls while waiting.
    """

    def __init__(self, link: ModbusLink, clock: Clock, *, poll_s: float = 1.0) -> None:
        self._link = link
        self._clock = clock
        self._poll_s = poll_s
        self._limits: tuple[float, float] | None = None

    @classmethod
    def connect(
        cls, host: str, port: int, clock: Clock, *, timeout_s: float = 1.0, poll_s: float = 1.0
    ) -> ModbusChamber:
        link = ModbusLink(host, port, device_id=DEVICE_ID, timeout_s=timeout_s, instrument=NAME)
        link.connect()
        return cls(link, clock, poll_s=poll_s)

    def attach_clock(self, clock: Clock) -> None:
        """Wait and time out on the station clock from now on."""
        self._clock = clock

    def identify(self) -> InstrumentIdentity:
        return read_identity(self._link, Reg.MODEL, Reg.SERIAL, Reg.FIRMWARE, STRING_REGS)

    def probe(self) -> str:
        """'' when the controller answers and reports no fault, else what it reports."""
        return "chamber reports a fault" if self.read_state() == State.FAULT else ""

    # ------------------------------------------------------------ setpoint and limits

    def setpoint_limits(self) -> tuple[float, float]:
        if self._limits is None:
            low, high = self._link.read(Reg.SP_LIMIT_LOW, 2)
            self._limits = (_from_tenths(low), _from_tenths(high))
        return self._limits

    def set_setpoint(self, temp_c: float) -> None:
        low, high = self.setpoint_limits()
        if not low <= temp_c <= high:
            raise SetpointOutOfRange(
                f"chamber setpoint {temp_c:g} C is outside the controller's limits "
                f"[{low:g}, {high:g}] C: change the procedure's temperatures or the limits",
                instrument=NAME,
            )
        try:
            self._link.write(Reg.SETPOINT, _to_tenths(temp_c))
        except ModbusRefused as exc:
            if exc.exception_code != 3:
                raise
            self._limits = None  # the limits may have been changed at the controller
            raise SetpointOutOfRange(
                f"the chamber refused setpoint {temp_c:g} C as out of range: check its "
                "setpoint limits (registers 602/603)",
                instrument=NAME,
            ) from exc

    def read_setpoint(self) -> float:
        return _from_tenths(self._link.read(Reg.SETPOINT, 1)[0])

    def read_temperature(self) -> float:
        return _from_tenths(self._link.read(Reg.PROCESS_VALUE, 1)[0])

    def read_state(self) -> State:
        raw = self._link.read(Reg.STATE, 1)[0]
        try:
            return State(raw)
        except ValueError:
            raise InstrumentError(
                f"the chamber reports an unknown state {raw}: see its manual", instrument=NAME
            ) from None

    def set_ramp_rate(self, c_per_min: float) -> None:
        """Ramp limit in C/min; 0 lets the chamber change as fast as it can."""
        if not 0 <= c_per_min <= MAX_RAMP_C_PER_MIN:
            raise ValueError(
                f"ramp rate must be 0..{MAX_RAMP_C_PER_MIN:g} C/min, got {c_per_min!r}"
            )
        self._link.write(Reg.RAMP_RATE, int(round(c_per_min * TENTHS)))

    # ------------------------------------------------------------ run/stop

    def run(self) -> None:
        self._link.write(Reg.RUN, 1)

    def stop(self) -> None:
        self._link.write(Reg.RUN, 0)

    def is_running(self) -> bool:
        return self._link.read(Reg.RUN, 1)[0] == 1

    def wait_setpoint(self, band_c: float, timeout_s: float) -> float:
        if not band_c > 0:
            raise ValueError(f"band must be positive, got {band_c!r} C")
        setpoint = self.read_setpoint()
        if not self.is_running():
            raise InstrumentError(
                f"the chamber is stopped, so it will not reach {setpoint:g} C: call run() first",
                instrument=NAME,
            )
        deadline = self._clock.now_s() + timeout_s
        while True:
            pv = self.read_temperature()
            if abs(pv - setpoint) <= band_c:
                return pv
            if self.read_state() == State.FAULT:
                raise ChamberSetpointNotReached(
                    f"the chamber reports a fault at {pv:g} C and cannot reach {setpoint:g} C "
                    "(compressor or heater fault?): check the chamber, then rerun",
                    instrument=NAME,
                )
            if self._clock.now_s() >= deadline:
                raise ChamberSetpointNotReached(
                    f"the chamber did not reach {setpoint:g} +/- {band_c:g} C within "
                    f"{timeout_s:g} s (now {pv:g} C): check the chamber door, the compressor "
                    "and the ramp rate, or lengthen the timeout",
                    instrument=NAME,
                )
            self._clock.sleep_s(self._poll_s)

    def safe_state(self, safe_temp_c: float = 25.0) -> None:
        """Head back to a safe temperature, still running so the air actually gets there."""
        low, high = self.setpoint_limits()
        self._link.write(Reg.SETPOINT, _to_tenths(min(max(safe_temp_c, low), high)))
        self._link.write(Reg.RUN, 1)

    def close(self) -> None:
        self._link.close()

    # ------------------------------------------------------------ safe-state readback, watchdog

    def check_safe(self, safe_temp_c: float) -> SafeReadback:
        """Read back whether the controller holds the safe setpoint (within its limits)."""
        low, high = self.setpoint_limits()
        target = min(max(safe_temp_c, low), high)
        setpoint = self.read_setpoint()
        air = self.read_temperature()
        running = "running" if self.is_running() else "stopped"
        detail = f"setpoint {setpoint:g} C (safe {target:g} C), air {air:g} C, {running}"
        return SafeReadback(abs(setpoint - target) <= 0.5 / TENTHS, detail)

    def reconnect(self, timeout_s: float | None = None) -> None:
        reopen_link(self._link, timeout_s)

    def watchdog_check(self) -> None:
        """Raise ChamberFault when the controller reports its FAULT state."""
        if self.read_state() == State.FAULT:
            air = self.read_temperature()
            raise ChamberFault(
                f"the chamber reports a fault at {air:g} C (setpoint {self.read_setpoint():g} "
                "C): compressor, heater or sensor fault; check the chamber, then rerun",
                instrument=NAME,
            )


# ---------------------------------------------------------------- configuration (chamber.watlow-f4)


class Settings(BaseModel):
    """station.yaml `instruments.chamber` for `driver: chamber.watlow-f4` (the default)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    address: str = Field(description="host:port of the controller's Modbus TCP server")
    timeout_s: float = Field(1.0, gt=0, le=60, description="wall seconds per Modbus reply")
    poll_s: float = Field(
        1.0, gt=0, le=60, description="station seconds between polls while waiting"
    )

    @field_validator("address")
    @classmethod
    def _address(cls, value: str) -> str:
        return check_host_port(value)


def factory(settings: dict[str, Any]) -> ModbusChamber:
    """Validate `settings` (ValidationError propagates), connect, return the driver."""
    s = Settings.model_validate(settings)
    host, port = split_host_port(s.address)
    return ModbusChamber.connect(
        host, port, ScaledClock(1.0), timeout_s=s.timeout_s, poll_s=s.poll_s
    )
