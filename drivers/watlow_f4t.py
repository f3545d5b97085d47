"""Watlow F4T temperature controller over Modbus TCP (map: drivers.watlow_f4t_map).

Loop `loop`'s setpoint, process value and setpoint range are float32 register pairs, low word
first, each written in one request. Run is the loop's control mode AUTO (after terminating a
profile that is running or paused, so the constant setpoint is what the loop follows); stop is
mode OFF; running is the mode in effect not being OFF. The F4T's ramp settings are not part of
the documented remote map, so the ramp rate is done by this driver (`drivers.ramped_chamber`).
Temperatures are converted when the controller's units register says F; the station speaks C.
A chamber fault is an active alarm (alarms 1..`alarm_count`): `wait_setpoint` raises
`ChamberAlarm` naming it.
"""

from __future__ import annotations

import logging
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator

from common.address import parse_host_port
from common.clock import Clock
from drivers.errors import ProtocolError, SetpointOutOfRange
from drivers.modbus_link import ModbusLink, ModbusRefused, reopen_link
from drivers.protocols import InstrumentIdentity
from drivers.ramped_chamber import RampedChamber
from drivers.watlow_f4t_map import (
    ALARM_INACTIVE,
    ALARM_TEXT,
    DEVICE_ID,
    PART_NUMBER_REGS,
    PROFILE_ACTIVE,
    Code,
    Reg,
    alarm_reg,
    c_to_f,
    f_to_c,
    float_to_regs,
    loop_reg,
    regs_to_float,
    regs_to_text,
)

log = logging.getLogger(__name__)

NAME = "Watlow F4T chamber controller"


class Settings(BaseModel):
    """station.yaml `instruments.chamber` for `driver: watlow-f4t`."""

    model_config = ConfigDict(extra="forbid")

    address: str = Field(description="host:port of the F4T's Modbus TCP server (port 502)")
    timeout_s: float = Field(1.0, gt=0.0, le=60.0, allow_inf_nan=False)
    poll_s: float = Field(1.0, gt=0.0, le=600.0, allow_inf_nan=False)
    device_id: int = Field(DEVICE_ID, ge=1, le=247)
    loop: int = Field(1, ge=1, le=4, description="the control loop of the chamber air")
    alarm_count: int = Field(6, ge=0, le=14, description="alarms 1..n checked for a fault")
    serial: str = Field("", max_length=40, description="nameplate serial (not on the wire)")

    @field_validator("address")
    @classmethod
    def _host_port(cls, address: str) -> str:
        if parse_host_port(address) is None:
            raise ValueError(f"address must be host:port (e.g. 192.168.0.20:502), got {address!r}")
        return address


def factory(settings: dict[str, Any]) -> WatlowF4T:
    """Validate `settings`, connect and return the driver (station clock: `attach_clock`)."""
    cfg = Settings.model_validate(settings)
    host_port = parse_host_port(cfg.address)
    assert host_port is not None
    link = ModbusLink(
        *host_port, device_id=cfg.device_id, timeout_s=cfg.timeout_s, instrument=NAME
    )
    link.connect()
    return WatlowF4T(
        link,
        poll_s=cfg.poll_s,
        loop=cfg.loop,
        alarm_count=cfg.alarm_count,
        serial=cfg.serial,
    )


class WatlowF4T(RampedChamber):
    """`drivers.protocols.Chamber` for a Watlow F4T loop.

    Args:
        link: an open or openable `ModbusLink` to the controller.
        clock: the station clock (default `ScaledClock(1.0)` until `attach_clock`).
        poll_s: station seconds between polls while waiting for the setpoint.
        loop: the loop that controls the chamber air (1..4).
        alarm_count: alarms 1..n whose state counts as a chamber fault.
        serial: the chamber's serial number for the certificate (the F4T does not report it).
    """

    def __init__(
        self,
        link: ModbusLink,
        clock: Clock | None = None,
        *,
        poll_s: float = 1.0,
        loop: int = 1,
        alarm_count: int = 6,
        serial: str = "",
    ) -> None:
        super().__init__(NAME, clock, poll_s=poll_s)
        self._link = link
        self._loop = loop
        self._alarm_count = alarm_count
        self._serial = serial
        self._fahrenheit: bool | None = None

    def _reg(self, reg: Reg) -> int:
        return loop_reg(reg, self._loop)

    def identify(self) -> InstrumentIdentity:
        part = regs_to_text(self._link.read(Reg.PART_NUMBER, PART_NUMBER_REGS))
        return InstrumentIdentity(
            manufacturer="Watlow", model=part or "F4T", serial=self._serial
        )

    # ------------------------------------------------------------ units

    def _is_fahrenheit(self) -> bool:
        if self._fahrenheit is None:
            code = self._link.read(Reg.UNITS, 1)[0]
            if code not in (Code.CELSIUS, Code.FAHRENHEIT):
                raise ProtocolError(
                    f"the {NAME} reports temperature units code {code} (expected 15 C or "
                    "30 F): check the controller's Modbus map",
                    instrument=NAME,
                )
            self._fahrenheit = code == Code.FAHRENHEIT
        return self._fahrenheit

    def _to_c(self, value: float) -> float:
        return round(f_to_c(value), 3) if self._is_fahrenheit() else value

    def _from_c(self, temp_c: float) -> float:
        return c_to_f(temp_c) if self._is_fahrenheit() else temp_c

    def _read_float(self, reg: Reg) -> float:
        return self._to_c(regs_to_float(self._link.read(self._reg(reg), 2)))

    # ------------------------------------------------------------ wire primitives

    def _read_limits(self) -> tuple[float, float]:
        regs = self._link.read(self._reg(Reg.RANGE_LOW), 4)  # low pair then high pair
        return self._to_c(regs_to_float(regs[0:2])), self._to_c(regs_to_float(regs[2:4]))

    def _write_setpoint(self, temp_c: float) -> None:
        address = self._reg(Reg.SETPOINT)
        try:
            self._link.write_many(address, float_to_regs(self._from_c(temp_c)))
        except ModbusRefused as exc:
            if exc.exception_code != 3:
                raise
            raise SetpointOutOfRange(
                f"the chamber refused setpoint {temp_c:g} C as out of range: check loop "
                f"{self._loop}'s setpoint range (registers {self._reg(Reg.RANGE_LOW)}/"
                f"{self._reg(Reg.RANGE_HIGH)})",
                instrument=NAME,
            ) from exc

    def _read_wire_setpoint(self) -> float:
        return self._read_float(Reg.SETPOINT)

    def _read_pv(self) -> float:
        return self._read_float(Reg.PROCESS_VALUE)

    def _start(self) -> None:
        if self._link.read(Reg.PROFILE_STATE, 1)[0] in PROFILE_ACTIVE:
            log.info("%s: terminating the running profile to hold a constant setpoint", NAME)
            self._link.write(Reg.PROFILE_ACTION, Code.TERMINATE)
        self._link.write(self._reg(Reg.CONTROL_MODE), Code.AUTO)

    def _standby(self) -> None:
        self._link.write(self._reg(Reg.CONTROL_MODE), Code.OFF)

    def _running(self) -> bool:
        return self._link.read(self._reg(Reg.ACTUAL_MODE), 1)[0] != Code.OFF

    def _alarms(self) -> list[str]:
        active = []
        for alarm in range(1, self._alarm_count + 1):
            code = self._link.read(alarm_reg(alarm), 1)[0]
            if code not in ALARM_INACTIVE:
                what = ALARM_TEXT.get(code, f"alarm state {code}")
                active.append(f"{what} on alarm {alarm}")
        return active

    def reconnect(self, timeout_s: float | None = None) -> None:
        reopen_link(self._link, timeout_s)
        self._fahrenheit = None  # a re-plugged controller may have been set to other units

    def close(self) -> None:
        self._link.close()
