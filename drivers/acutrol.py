"""Rate table on an Acutronic ACUTROL controller, over its ASCII command language on TCP.

The dialect (commands, replies, status word, fault and error codes) is stated in
`drivers.acutrol_codes`. Semantics follow the Modbus servo driver (`drivers.rate_table`) so
the engine cannot tell them apart, with these differences, made honestly:

- Encoder counts: the ACUTROL reports position in degrees, not raw counts. `read_status`
  derives `encoder_counts` as round(position x counts_per_rev / 360) with `counts_per_rev`
  from the settings (the encoder the fixture's encoder input sees); `encoder_counts` is that
  count wrapped to 32 bits, `encoder_counts_unwrapped` the count itself (the ACUTROL's
  position does not wrap, so nothing is lost between reads).
- Zeroing: the remote interface has no command to re-zero the position transducer (its zero
  is a controller setup parameter). `zero_encoder` takes the current position as the
  driver's zero: later positions, demands and derived counts are relative to it.
- Move time: the ACUTROL plans position moves from the mode's acceleration and rate limits.
  `move_to(..., move_time_s=T)` sets them for a triangular move of that length over the
  distance to go (acceleration 4d/T^2, peak rate 2d/T), so the move takes T when the table
  can do it, longer when a limit of the controller is lower.
- Controller time: `:system:time?` in the same request as the feedback.

Station configuration (`instruments.rate_table`, driver `acutrol`): see `Settings`.
"""

from __future__ import annotations

import logging
import math
from typing import Any

from pydantic import Field

from common.address import TcpInstrumentSettings
from common.clock import Clock, ScaledClock
from drivers.acutrol_codes import Err, StatusBit, fault_text
from drivers.errors import (
    ProtocolError,
    SetpointOutOfRange,
    TableFault,
)
from drivers.protocols import InstrumentIdentity, TableStatus
from drivers.table_waits import TableWaits
from drivers.tcp_lines import LineLink

log = logging.getLogger(__name__)

NAME = "rate table"
_SAFETY_ERRORS = (Err.SAFETY_OPEN, Err.FAULT_LATCHED, Err.ESTOP)


class AcutrolRefused(ProtocolError):  # noqa: N818 - named like drivers.errors
    """The controller answered `ERR <code>,"<text>"` to a command."""

    def __init__(self, message: str, *, code: int, instrument: str | None = None) -> None:
        super().__init__(message, instrument=instrument)
        self.code = code


class Settings(TcpInstrumentSettings):
    """`instruments.rate_table` in station.yaml for driver `acutrol`."""

    address: str = Field(description="host:port of the ACUTROL's TCP command interface")
    axis: int = Field(1, ge=1, le=8, description="the table's axis number on the controller")
    counts_per_rev: int = Field(
        1 << 20, ge=360, le=1 << 40,
        description="counts per revolution of the table's encoder as the fixture sees it "
        "(encoder counts are derived from the ACUTROL's position)",
    )


def factory(settings: dict[str, Any]) -> AcutrolTable:
    """The `rate_table.acutrol` driver: validate, connect, return it."""
    s = Settings.model_validate(settings)
    host, port = s.host_port()
    link = LineLink(host, port, timeout_s=s.timeout_s, instrument=NAME)
    link.connect()
    return AcutrolTable(
        link, ScaledClock(1.0), axis=s.axis, counts_per_rev=s.counts_per_rev, poll_s=s.poll_s
    )


def _num(value: float) -> str:
    return f"{value:.6f}"


class AcutrolTable(TableWaits):
    """`drivers.protocols.RateTable` over the ACUTROL command language (see module doc)."""

    def __init__(
        self, link: LineLink, clock: Clock, *, axis: int = 1, counts_per_rev: int = 1 << 20,
        poll_s: float = 0.05,
    ) -> None:
        self._link = link
        self._clock = clock
        self._axis = axis
        self._cpr = counts_per_rev
        self._poll_s = poll_s
        self._zero_deg = 0.0
        self._limits: tuple[float, float] | None = None
        self._rate_cmd_dps: float | None = None
        self._pos_cmd_deg: float | None = None

    def attach_clock(self, clock: Clock) -> None:
        """Use the station's clock for waits and polls (ScaledClock(1.0) until called)."""
        self._clock = clock

    # ------------------------------------------------------------ the wire

    def _send(self, line: str) -> str:
        """One request line; the reply, or a typed exception for an `ERR` reply."""
        reply = self._link.query(line)
        if not reply.startswith("ERR"):
            return reply
        code_text, _, text = reply[3:].strip().partition(",")
        try:
            code = int(code_text)
        except ValueError:
            raise ProtocolError(
                f"the rate table answered {line!r} with {reply!r}, not an ACUTROL reply",
                instrument=NAME,
            ) from None
        text = text.strip().strip('"')
        if code in _SAFETY_ERRORS:
            self.check()  # raises InterlockOpen / TableFault with the latched state
        if code == Err.OUT_OF_RANGE:
            raise SetpointOutOfRange(
                f"the rate table refused {line!r}: {text}; check the procedure's rates and "
                "accelerations against the table's limits",
                instrument=NAME,
            )
        raise AcutrolRefused(
            f"the rate table refused {line!r}: error {code}, {text}", code=code, instrument=NAME
        )

    def _command(self, line: str) -> None:
        reply = self._send(line)
        if reply != "OK":
            raise ProtocolError(
                f"the rate table answered {line!r} with {reply!r}, expected OK", instrument=NAME
            )

    def _numbers(self, line: str, count: int) -> list[float]:
        reply = self._send(line)
        try:
            values = [float(v) for v in reply.split(";")]
        except ValueError:
            values = []
        if len(values) != count or not all(math.isfinite(v) for v in values):
            raise ProtocolError(
                f"the rate table answered {line!r} with {reply!r}, expected {count} numbers "
                "separated by ';'",
                instrument=NAME,
            )
        return values

    # ------------------------------------------------------------ identity and status

    def identify(self) -> InstrumentIdentity:
        reply = self._send("*IDN?")
        parts = [p.strip() for p in reply.split(",")]
        if len(parts) != 4:
            raise ProtocolError(
                f"the rate table answered *IDN? with {reply!r}, expected "
                "manufacturer,model,serial,firmware",
                instrument=NAME,
            )
        return InstrumentIdentity(*parts)

    def counts_per_rev(self) -> int:
        return self._cpr

    def _hard_limits(self) -> tuple[float, float]:
        if self._limits is None:
            values = self._send(f":limit:absolute? {self._axis}").split(",")
            try:
                self._limits = (float(values[0]), float(values[1]))
            except (ValueError, IndexError):
                raise ProtocolError(
                    f"the rate table answered :limit:absolute? with {','.join(values)!r}, "
                    "expected rate,acc,jerk,pos_lo,pos_hi,vtrip",
                    instrument=NAME,
                ) from None
        return self._limits

    def max_rate_dps(self) -> float:
        """The table's absolute rate limit, as the controller reports it."""
        return self._hard_limits()[0]

    def max_accel_dps2(self) -> float:
        """The table's absolute acceleration limit, as the controller reports it."""
        return self._hard_limits()[1]

    def read_status(self) -> TableStatus:
        a = self._axis
        pos, rate, word, fault, time_s = self._numbers(
            f":read:pos? {a};rate? {a};:status? {a};:fault? {a};:system:time?", 5
        )
        bits = StatusBit(int(word) & 0xFF)
        position = pos - self._zero_deg
        counts = round(position * self._cpr / 360.0)
        return TableStatus(
            ready=StatusBit.READY in bits,
            enabled=StatusBit.CLOSED in bits,
            fault=StatusBit.FAULT in bits,
            in_position=StatusBit.IN_POSITION in bits,
            at_rate=StatusBit.AT_RATE in bits,
            moving=StatusBit.MOVING in bits,
            interlock_open=StatusBit.SAFETY_OPEN in bits,
            fault_code=int(fault),
            encoder_counts=counts & 0xFFFF_FFFF,
            position_deg=position,
            rate_dps=rate,
            controller_time_s=time_s,
            encoder_counts_unwrapped=counts,
        )

    def fault_text(self, code: int) -> str:
        return fault_text(code)

    # ------------------------------------------------------------ control

    def enable(self) -> None:
        self.check()
        self._command(f":interlock:close {self._axis}")
        status = self._wait(lambda s: s.enabled, 1.0, "enable")
        log.info("rate table enabled at %.3f deg", status.position_deg)

    def disable(self) -> None:
        self._command(f":interlock:open {self._axis}")

    def reset_fault(self) -> None:
        self._command(f":interlock:reset {self._axis}")
        status = self.read_status()
        if status.fault and not status.interlock_open:
            raise TableFault(
                f"the rate table's fault did not clear: {fault_text(status.fault_code)}",
                fault_code=status.fault_code,
                instrument=NAME,
            )
        self.check(status)

    def zero_encoder(self) -> None:
        """Take the current position as zero (in the driver: see the module doc)."""
        self._zero_deg += self.read_status().position_deg
        self._pos_cmd_deg = None

    def set_rate(self, rate_dps: float, accel_dps2: float | None = None) -> None:
        self._rate_command(rate_dps, accel_dps2, self.max_rate_dps())
        a = self._axis
        parts = [] if accel_dps2 is None else [f":limit:acc rate,{a},{_num(accel_dps2)}"]
        parts += [f":mode:rate {a}", f":demand:rate {a},{_num(rate_dps)}"]
        self._command(";".join(parts))
        self.check()

    def move_to(
        self, angle_deg: float, *, accel_dps2: float | None = None, move_time_s: float | None = None
    ) -> None:
        self._check_move(accel_dps2, move_time_s)
        a = self._axis
        parts = []
        if accel_dps2 is not None:
            parts.append(f":limit:acc pos,{a},{_num(accel_dps2)}")
        if move_time_s is not None:
            distance = abs(angle_deg - self.read_status().position_deg)
            if distance > 1e-6:
                parts.append(f":limit:acc pos,{a},{_num(4.0 * distance / move_time_s**2)}")
                parts.append(f":limit:rate pos,{a},{_num(2.0 * distance / move_time_s)}")
        self._move_command(angle_deg)
        parts += [f":mode:position {a}", f":demand:position {a},{_num(angle_deg + self._zero_deg)}"]
        self._command(";".join(parts))
        self.check()

    # ------------------------------------------------------------ waits

    # ------------------------------------------------------------ shutdown

    def _demand_stop(self) -> None:
        """Demand rate 0 (safe_state then waits for rest and opens the axis interlock: drive
        off)."""
        self._command(f":mode:rate {self._axis};:demand:rate {self._axis},{_num(0.0)}")

    def close(self) -> None:
        self._link.close()
