"""Servo rate table with an optical encoder, over Modbus TCP (map: drivers.rate_table_map).

Commands that change motion write MODE..MOVE_TIME (registers 1..9) in one request, so the
controller plans a move once from a consistent command set. Status and the feedback snapshot
(registers 20..29) are read in one request. Waits are in station seconds on the injected
clock; each Modbus reply has its own wall timeout in `ModbusLink`.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator

from drivers.address import check_host_port, split_host_port
from drivers.clock import Clock, ScaledClock
from drivers.errors import InstrumentError, InstrumentTimeout, InterlockOpen, TableFault
from drivers.modbus_link import (
    ModbusLink,
    ModbusRefused,
    Unwrapper,
    i32_to_regs,
    read_identity,
    regs_to_i32,
    regs_to_u32,
)
from drivers.protocols import InstrumentIdentity, TableStatus
from drivers.rate_table_map import (
    COUNTS_PER_REV,
    DEVICE_ID,
    FAULT_TEXT,
    MAX_RATE_DPS,
    STRING_REGS,
    Control,
    Fault,
    Mode,
    Reg,
    Status,
)

log = logging.getLogger(__name__)

NAME = "rate table"
DEFAULT_MAX_ACCEL_DPS2 = 2000.0  # the drive's acceleration limit (not in the register map)
_NO_BITS = Control(0)
_STATUS_FIRST = Reg.STATUS
_STATUS_COUNT = Reg.SNAPSHOT_TIME + 2 - Reg.STATUS  # 20..29: status, fault, snapshot
_CMD_FIRST = Reg.MODE
_CMD_COUNT = Reg.MOVE_TIME + 2 - Reg.MODE  # 1..9
# a stale AT_RATE / IN_POSITION from the previous command must not end a wait for a new one
_RATE_MATCH_DPS = 0.5
_RATE_MATCH_REL = 0.005
_POSITION_MATCH_DEG = 0.05


def fault_message(code: int) -> str:
    try:
        return FAULT_TEXT[Fault(code)]
    except ValueError:
        return f"unknown fault code {code}: see the controller's manual, then reset the fault"


class ModbusRateTable:
    """`drivers.protocols.RateTable` over Modbus TCP.

    Args:
        link: an open or openable `ModbusLink` to the controller.
        clock: the station clock; waits and polls use its time.
        poll_s: station seconds between status polls while waiting.
    """

    def __init__(self, link: ModbusLink, clock: Clock, *, poll_s: float = 0.05) -> None:
        self._link = link
        self._clock = clock
        self._poll_s = poll_s
        self._counts = Unwrapper(1 << 32)
        self._time_us = Unwrapper(1 << 32)
        self._rate_cmd_dps: float | None = None
        self._pos_cmd_deg: float | None = None
        self.max_accel_dps2 = DEFAULT_MAX_ACCEL_DPS2

    @classmethod
    def connect(
        cls, host: str, port: int, clock: Clock, *, timeout_s: float = 1.0, poll_s: float = 0.05
    ) -> ModbusRateTable:
        link = ModbusLink(host, port, device_id=DEVICE_ID, timeout_s=timeout_s, instrument=NAME)
        link.connect()
        return cls(link, clock, poll_s=poll_s)

    # ------------------------------------------------------------ identity and status

    def identify(self) -> InstrumentIdentity:
        return read_identity(self._link, Reg.MODEL, Reg.SERIAL, Reg.FIRMWARE, STRING_REGS)

    def counts_per_rev(self) -> int:
        return COUNTS_PER_REV

    def attach_clock(self, clock: Clock) -> None:
        self._clock = clock

    def rate_limits(self) -> tuple[float, float]:
        """(largest |rate| deg/s, largest acceleration deg/s^2) for the pre-flight."""
        return MAX_RATE_DPS, self.max_accel_dps2

    def probe(self) -> str:
        """'' when the table answers with no fault and a closed interlock, else which."""
        status = self.read_status()
        if status.interlock_open:
            return "interlock open"
        return f"fault code {status.fault_code}" if status.fault else ""

    def read_status(self) -> TableStatus:
        regs = self._link.read(_STATUS_FIRST, _STATUS_COUNT)
        bits = Status(regs[0])

        def at(reg: Reg) -> list[int]:
            i = reg - _STATUS_FIRST
            return regs[i : i + 2]

        counts = regs_to_u32(at(Reg.ENCODER_COUNTS))
        return TableStatus(
            ready=Status.READY in bits,
            enabled=Status.ENABLED in bits,
            fault=Status.FAULT in bits,
            in_position=Status.IN_POSITION in bits,
            at_rate=Status.AT_RATE in bits,
            moving=Status.MOVING in bits,
            interlock_open=Status.INTERLOCK_OPEN in bits,
            fault_code=regs[1],
            encoder_counts=counts,
            position_deg=regs_to_i32(at(Reg.POS_FB)) / 1000.0,
            rate_dps=regs_to_i32(at(Reg.RATE_FB)) / 1000.0,
            controller_time_s=self._time_us(regs_to_u32(at(Reg.SNAPSHOT_TIME))) * 1e-6,
            encoder_counts_unwrapped=self._counts(counts),
        )

    def check(self, status: TableStatus | None = None) -> TableStatus:
        """Raise InterlockOpen or TableFault if the table reports either; else the status."""
        status = status or self.read_status()
        if status.interlock_open:
            raise InterlockOpen(
                "the rate table's safety interlock is open (door or guard): close it, then "
                "reset the fault and enable the table again",
                fault_code=status.fault_code,
                instrument=NAME,
            )
        if status.fault:
            raise TableFault(
                f"rate table fault {status.fault_code}: {fault_message(status.fault_code)}; "
                "the table stopped and is disabled",
                fault_code=status.fault_code,
                instrument=NAME,
            )
        return status

    # ------------------------------------------------------------ control

    def _control(self, set_bits: Control, clear_bits: Control = _NO_BITS) -> None:
        current = Control(self._link.read(Reg.CONTROL, 1)[0] & 0x0F)
        current &= ~(Control.FAULT_RESET | Control.ZERO_ENCODER)  # edge bits: never re-send
        self._link.write(Reg.CONTROL, int((current | set_bits) & ~clear_bits))

    def enable(self) -> None:
        self.check()
        self._control(Control.ENABLE, Control.HALT)
        status = self._wait(lambda s: s.enabled, 1.0, "enable")
        log.info("rate table enabled at %.3f deg", status.position_deg)

    def disable(self) -> None:
        self._link.write(Reg.CONTROL, 0)

    def reset_fault(self) -> None:
        self._control(Control.FAULT_RESET)
        status = self.read_status()
        if status.fault and not status.interlock_open:
            raise TableFault(
                f"the rate table's fault did not clear: {fault_message(status.fault_code)}",
                fault_code=status.fault_code,
                instrument=NAME,
            )
        self.check(status)

    def zero_encoder(self) -> None:
        self._control(Control.ZERO_ENCODER)
        self._counts = Unwrapper(1 << 32)
        self._pos_cmd_deg = None

    def _command(
        self, mode: Mode, *, pos_deg: float | None = None, rate_dps: float | None = None,
        accel_dps2: float | None = None, move_time_s: float | None = None,
    ) -> None:
        regs = self._link.read(_CMD_FIRST, _CMD_COUNT)
        new = list(regs)

        def put(reg: Reg, value: float) -> None:
            i = reg - _CMD_FIRST
            new[i : i + 2] = i32_to_regs(int(round(value)))

        new[0] = int(mode)
        if pos_deg is not None:
            put(Reg.POS_CMD, pos_deg * 1000.0)
        if rate_dps is not None:
            put(Reg.RATE_CMD, rate_dps * 1000.0)
        if accel_dps2 is not None:
            put(Reg.ACCEL_LIMIT, accel_dps2 * 1000.0)
        if move_time_s is not None:
            put(Reg.MOVE_TIME, move_time_s * 1000.0)
        try:
            self._link.write_many(_CMD_FIRST, new)
        except ModbusRefused as exc:
            raise InstrumentError(
                f"the rate table refused the command (mode {mode.name.lower()}, position "
                f"{pos_deg} deg, rate {rate_dps} deg/s, acceleration {accel_dps2} deg/s^2, move "
                f"time {move_time_s} s): a value is outside its limits; check the procedure",
                instrument=NAME,
            ) from exc
        self.check()

    def set_rate(self, rate_dps: float, accel_dps2: float | None = None) -> None:
        if not abs(rate_dps) <= MAX_RATE_DPS:
            raise ValueError(
                f"rate {rate_dps} deg/s is beyond the table's limit of {MAX_RATE_DPS} deg/s"
            )
        if accel_dps2 is not None and not accel_dps2 > 0:
            raise ValueError(f"acceleration must be positive, got {accel_dps2} deg/s^2")
        self._rate_cmd_dps = float(rate_dps)
        self._pos_cmd_deg = None
        self._command(Mode.RATE, rate_dps=rate_dps, accel_dps2=accel_dps2)

    def move_to(
        self, angle_deg: float, *, accel_dps2: float | None = None, move_time_s: float | None = None
    ) -> None:
        if accel_dps2 is not None and move_time_s is not None:
            raise ValueError("give move_to either accel_dps2 or move_time_s, not both")
        if accel_dps2 is not None and not accel_dps2 > 0:
            raise ValueError(f"acceleration must be positive, got {accel_dps2} deg/s^2")
        if move_time_s is not None and not move_time_s > 0:
            raise ValueError(f"move time must be positive, got {move_time_s} s")
        self._pos_cmd_deg = float(angle_deg)
        self._rate_cmd_dps = None
        self._command(
            Mode.POSITION, pos_deg=angle_deg, accel_dps2=accel_dps2,
            move_time_s=move_time_s if move_time_s is not None else 0.0,
        )

    # ------------------------------------------------------------ waits

    def _wait(
        self, done: Callable[[TableStatus], bool], timeout_s: float, what: str
    ) -> TableStatus:
        deadline = self._clock.now_s() + timeout_s
        while True:
            status = self.check()
            if done(status):
                return status
            if self._clock.now_s() >= deadline:
                raise InstrumentTimeout(
                    f"the rate table did not {what} within {timeout_s:g} s (rate "
                    f"{status.rate_dps:.3f} deg/s, position {status.position_deg:.3f} deg, "
                    f"status {status}): check the load and the acceleration limit, or "
                    "lengthen the timeout",
                    instrument=NAME,
                )
            self._clock.sleep_s(self._poll_s)

    def wait_at_rate(self, timeout_s: float) -> TableStatus:
        cmd = self._rate_cmd_dps

        def done(s: TableStatus) -> bool:
            tolerance_dps = _RATE_MATCH_DPS + _RATE_MATCH_REL * abs(cmd or 0.0)
            near = cmd is None or abs(s.rate_dps - cmd) <= tolerance_dps
            return s.at_rate and near

        return self._wait(done, timeout_s, f"reach {cmd} deg/s")

    def wait_in_position(self, timeout_s: float) -> TableStatus:
        cmd = self._pos_cmd_deg

        def done(s: TableStatus) -> bool:
            near = cmd is None or abs(s.position_deg - cmd) <= _POSITION_MATCH_DEG
            return s.in_position and near

        return self._wait(done, timeout_s, f"come to rest at {cmd} deg")

    # ------------------------------------------------------------ shutdown

    def safe_state(self, timeout_s: float = 30.0) -> None:
        status = self.read_status()
        if status.enabled and not status.fault and status.moving:
            self._link.write(Reg.CONTROL, int(Control.ENABLE | Control.HALT))
            try:
                self._wait(lambda s: not s.moving, timeout_s, "stop")
            except InstrumentError as exc:  # a fault stops the table anyway
                log.warning("while stopping the rate table: %s", exc)
        self._link.write(Reg.CONTROL, 0)

    def close(self) -> None:
        self._link.close()


# ---------------------------------------------------------------- configuration
# (rate_table.modbus-servo; minimal, for the registry: the tables engineer's profile version
# replaces it)


class Settings(BaseModel):
    """station.yaml `instruments.rate_table` for `driver: rate_table.modbus-servo`."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    address: str = Field(description="host:port of the drive's Modbus TCP server")
    timeout_s: float = Field(1.0, gt=0, le=60, description="wall seconds per Modbus reply")
    poll_s: float = Field(0.05, gt=0, le=10, description="station seconds between polls")
    max_accel_dps2: float = Field(
        DEFAULT_MAX_ACCEL_DPS2, gt=0, le=1e6, description="the drive's acceleration limit"
    )

    @field_validator("address")
    @classmethod
    def _address(cls, value: str) -> str:
        return check_host_port(value)


def factory(settings: dict[str, Any]) -> ModbusRateTable:
    s = Settings.model_validate(settings)
    table = ModbusRateTable.connect(
        *split_host_port(s.address), ScaledClock(1.0), timeout_s=s.timeout_s, poll_s=s.poll_s
    )
    table.max_accel_dps2 = s.max_accel_dps2
    return table
