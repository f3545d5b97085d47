"""Servo rate table with an optical encoder, over Modbus TCP, register map from a profile.

The register map (addresses, types, scaling, word order, status/control bits, fault codes,
counts per revolution, limits) is a YAML profile (`drivers.servo_profile`); the default,
`servo-default`, is the station's own controller (`drivers/rate_table_map.py`).
Commands that change motion write the command group (mode .. move_time) in one request, so
the controller plans a move once from a consistent command set. Status and the feedback
snapshot are read in one request. Waits are in station seconds on the injected clock; each
Modbus reply has its own wall timeout in `ModbusLink`.

Station configuration (`instruments.rate_table`, driver `modbus-servo`): see `Settings`.
"""

from __future__ import annotations

import logging
from typing import Any

from pydantic import Field, field_validator

from common.address import TcpInstrumentSettings
from common.clock import Clock, ScaledClock
from common.yaml_input import ConfigError
from drivers.errors import (
    ControllerHung,
    InstrumentError,
    TableFault,
)
from drivers.modbus_link import ModbusLink, ModbusRefused, Unwrapper, regs_to_str, reopen_link
from drivers.protocols import InstrumentIdentity, SafeReadback, TableStatus
from drivers.servo_profile import (
    COMMAND_FIELDS,
    DEFAULT_PROFILE,
    STATUS_FIELDS,
    STRING_FIELDS,
    WATCHDOG_FIELDS,
    Register,
    ServoProfile,
    load_profile,
)
from drivers.table_waits import TableWaits

log = logging.getLogger(__name__)

NAME = "rate table"
# a stale AT_RATE / IN_POSITION from the previous command must not end a wait for a new one
SAFE_REST_DPS = 0.01  # |rate| below this, not moving: the table is at rest
# the heartbeat register must advance within this much station time (and readings further
# apart than the window are not compared: the 16-bit counter may have wrapped)
HEARTBEAT_STALL_S = 1.0
HEARTBEAT_WINDOW_S = 300.0


class Settings(TcpInstrumentSettings):
    """`instruments.rate_table` in station.yaml for driver `modbus-servo`."""

    address: str = Field(description="host:port of the drive's Modbus TCP server")
    device_id: int = Field(1, ge=0, le=255, description="Modbus unit/device id")
    profile: str = Field(
        DEFAULT_PROFILE,
        description="register map: a built-in profile's name (servo-default, "
        "servo-lowword-example) or the path of a profile YAML file",
    )

    @field_validator("profile")
    @classmethod
    def _profile(cls, v: str) -> str:
        try:
            load_profile(v)
        except ConfigError as exc:
            raise ValueError(f"the servo profile is not usable:\n{exc}") from None
        return v


def factory(settings: dict[str, Any]) -> ModbusRateTable:
    """The `rate_table.modbus-servo` driver: validate, connect, return it."""
    s = Settings.model_validate(settings)
    host, port = s.host_port()
    return ModbusRateTable.connect(
        host, port, ScaledClock(1.0), timeout_s=s.timeout_s, poll_s=s.poll_s,
        profile=load_profile(s.profile), device_id=s.device_id,
    )


def fault_message(code: int, profile: ServoProfile | None = None) -> str:
    return (profile or load_profile()).fault_text(code)


class ModbusRateTable(TableWaits):
    """`drivers.protocols.RateTable` over Modbus TCP.

    Args:
        link: an open or openable `ModbusLink` to the controller.
        clock: the station clock; waits and polls use its time.
        poll_s: station seconds between status polls while waiting.
        profile: the drive's register map (default: `servo-default`).
    """

    def __init__(
        self, link: ModbusLink, clock: Clock, *, poll_s: float = 0.05,
        profile: ServoProfile | None = None,
    ) -> None:
        self._link = link
        self._clock = clock
        self._poll_s = poll_s
        self.profile = profile or load_profile()
        regs = self.profile.registers
        self._counts = Unwrapper(1 << regs.encoder_counts.bits)
        self._time_raw = Unwrapper(1 << regs.time.bits)
        self._status_span = regs.span(STATUS_FIELDS)
        self._cmd_span = regs.span(COMMAND_FIELDS)
        self._control_mask = self.profile.control_bits.mask(
            "enable", "halt", "fault_reset", "zero_encoder"
        )
        self._rate_cmd_dps: float | None = None
        self._pos_cmd_deg: float | None = None

    @classmethod
    def connect(
        cls, host: str, port: int, clock: Clock, *, timeout_s: float = 1.0, poll_s: float = 0.05,
        profile: ServoProfile | None = None, device_id: int = 1,
    ) -> ModbusRateTable:
        link = ModbusLink(host, port, device_id=device_id, timeout_s=timeout_s, instrument=NAME)
        link.connect()
        return cls(link, clock, poll_s=poll_s, profile=profile)

    def attach_clock(self, clock: Clock) -> None:
        """Use the station's clock for waits and polls (ScaledClock(1.0) until called)."""
        self._clock = clock

    # ------------------------------------------------------------ identity and status

    def identify(self) -> InstrumentIdentity:
        """Model, serial and firmware strings read in one request; the manufacturer is the
        model string's first word when it has more than one."""
        regs = self.profile.registers
        first, end = regs.span(STRING_FIELDS)
        block = self._link.read(first, end - first)

        def text(name: str) -> str:
            field = getattr(regs, name)
            at = field.address - first
            return regs_to_str(block[at : at + field.count])

        model = text("model")
        maker, _, rest = model.partition(" ")
        return InstrumentIdentity(
            manufacturer=maker if rest else "", model=model, serial=text("serial"),
            firmware=text("firmware"),
        )

    def counts_per_rev(self) -> int:
        return self.profile.counts_per_rev

    def max_rate_dps(self) -> float:
        """The drive's rate limit from its profile (for pre-flight checks)."""
        return self.profile.limits.max_rate_dps

    def max_accel_dps2(self) -> float:
        """The highest acceleration limit the drive accepts, from its profile."""
        return self.profile.limits.max_accel_dps2

    def probe(self) -> str:
        """For the instrument lights: '' when the drive answers with no fault and a closed
        interlock, else which (raises an InstrumentError when it does not answer)."""
        status = self.read_status()
        if status.interlock_open:
            return "interlock open"
        return f"fault code {status.fault_code}" if status.fault else ""

    def read_status(self) -> TableStatus:
        first, end = self._status_span
        return self._status_from(self._link.read(first, end - first), first)

    def _status_from(self, block: list[int], first: int) -> TableStatus:
        p = self.profile
        regs = p.registers
        word = int(p.decode(regs.status, block, first, raw=True))

        def bit(name: str) -> bool:
            return bool(word >> getattr(p.status_bits, name) & 1)

        counts = int(p.decode(regs.encoder_counts, block, first, raw=True))
        time_raw = int(p.decode(regs.time, block, first, raw=True))
        return TableStatus(
            ready=bit("ready"),
            enabled=bit("enabled"),
            fault=bit("fault"),
            in_position=bit("in_position"),
            at_rate=bit("at_rate"),
            moving=bit("moving"),
            interlock_open=bit("interlock_open"),
            fault_code=int(p.decode(regs.fault_code, block, first, raw=True)),
            encoder_counts=counts,
            position_deg=p.decode(regs.position, block, first),
            rate_dps=p.decode(regs.rate, block, first),
            controller_time_s=self._time_raw(time_raw) * regs.time.scale,
            encoder_counts_unwrapped=self._counts(counts),
            controller_time_resolution_s=abs(regs.time.scale),  # one count of its register
        )

    def fault_text(self, code: int) -> str:
        return self.profile.fault_text(code)

    # ------------------------------------------------------------ control

    def _bits(self, *names: str) -> int:
        return self.profile.control_bits.mask(*names)

    def _control(self, set_bits: int, clear_bits: int = 0) -> None:
        address = self.profile.registers.control.address
        current = self._link.read(address, 1)[0] & self._control_mask
        current &= ~self._bits("fault_reset", "zero_encoder")  # edge bits: never re-send
        self._link.write(address, (current | set_bits) & ~clear_bits)

    def enable(self) -> None:
        self.check()
        self._control(self._bits("enable"), self._bits("halt"))
        status = self._wait(lambda s: s.enabled, 1.0, "enable")
        log.info("rate table enabled at %.3f deg", status.position_deg)

    def disable(self) -> None:
        self._link.write(self.profile.registers.control.address, 0)

    def reset_fault(self) -> None:
        self._control(self._bits("fault_reset"))
        status = self.read_status()
        if status.fault and not status.interlock_open:
            raise TableFault(
                "the rate table's fault did not clear: "
                f"{self.profile.fault_text(status.fault_code)}",
                fault_code=status.fault_code,
                instrument=NAME,
            )
        self.check(status)

    def zero_encoder(self) -> None:
        self._control(self._bits("zero_encoder"))
        self._counts = Unwrapper(1 << self.profile.registers.encoder_counts.bits)
        self._pos_cmd_deg = None

    def _command(
        self, mode: str, *, pos_deg: float | None = None, rate_dps: float | None = None,
        accel_dps2: float | None = None, move_time_s: float | None = None,
    ) -> None:
        p = self.profile
        regs = p.registers
        first, end = self._cmd_span
        block = list(self._link.read(first, end - first))

        def put(reg: Register, value: float) -> None:
            at = reg.address - first
            block[at : at + reg.words] = p.encode(reg, value)

        put(regs.mode, getattr(p.modes, mode))
        for reg, value in (
            (regs.position_command, pos_deg), (regs.rate_command, rate_dps),
            (regs.accel_limit, accel_dps2), (regs.move_time, move_time_s),
        ):
            if value is not None:
                put(reg, value)
        try:
            self._link.write_many(first, block)
        except ModbusRefused as exc:
            raise InstrumentError(
                f"the rate table refused the command (mode {mode}, position "
                f"{pos_deg} deg, rate {rate_dps} deg/s, acceleration {accel_dps2} deg/s^2, move "
                f"time {move_time_s} s): a value is outside its limits; check the procedure",
                instrument=NAME,
            ) from exc
        self.check()

    def set_rate(self, rate_dps: float, accel_dps2: float | None = None) -> None:
        self._rate_command(rate_dps, accel_dps2, self.profile.limits.max_rate_dps)
        self._command("rate", rate_dps=rate_dps, accel_dps2=accel_dps2)

    def move_to(
        self, angle_deg: float, *, accel_dps2: float | None = None, move_time_s: float | None = None
    ) -> None:
        self._check_move(accel_dps2, move_time_s)
        self._move_command(angle_deg)
        self._command(
            "position", pos_deg=angle_deg, accel_dps2=accel_dps2,
            move_time_s=move_time_s if move_time_s is not None else 0.0,
        )

    # ------------------------------------------------------------ waits

    # ------------------------------------------------------------ shutdown

    def _demand_stop(self) -> None:
        """The drive's halt bit, still enabled (safe_state then waits for rest, disables)."""
        self._link.write(self.profile.registers.control.address, self._bits("enable", "halt"))

    def close(self) -> None:
        self._link.close()

    # ------------------------------------------------------------ safe-state readback, watchdog

    def check_safe(self) -> SafeReadback:
        """Read back whether the table is at rest and disabled (its own status registers)."""
        status = self.read_status()
        at_rest = not status.moving and abs(status.rate_dps) < SAFE_REST_DPS
        state = "enabled" if status.enabled else "disabled"
        detail = f"rate {status.rate_dps:.3f} deg/s, {state}"
        if status.moving:
            detail += ", still moving"
        if status.fault:
            detail += f", fault {status.fault_code}: {fault_message(status.fault_code)}"
        if status.interlock_open:
            detail += ", interlock open"
        return SafeReadback(at_rest and not status.enabled, detail)

    def reconnect(self, timeout_s: float | None = None) -> None:
        reopen_link(self._link, timeout_s)

    def watchdog_check(self) -> None:
        """Raise TableFault/InterlockOpen on a fault or open interlock (at rest too), and
        ControllerHung when the controller's heartbeat register has stopped advancing."""
        first, end = self.profile.registers.span(WATCHDOG_FIELDS)
        block = self._link.read(first, end - first)  # status and heartbeat in one request
        self.check(self._status_from(block, first))  # raises with the fault's text
        hb = self.profile.registers.heartbeat
        if hb is None:
            return  # this profile's controller has no heartbeat register to judge
        beat = int(self.profile.decode(hb, block, first, raw=True))
        now = self._clock.now_s()
        last = getattr(self, "_heartbeat", None)
        if last is not None and beat == last[0] and 0 < now - last[1] < HEARTBEAT_WINDOW_S:
            if now - last[1] >= HEARTBEAT_STALL_S:
                raise ControllerHung(
                    f"the rate table's controller heartbeat (register {hb.address}) has "
                    f"not advanced for {now - last[1]:.1f} s: the controller has hung; power-"
                    "cycle it before moving the table",
                    instrument=NAME,
                )
            return  # too soon to judge: keep the first reading of this value
        self._heartbeat = (beat, now)
