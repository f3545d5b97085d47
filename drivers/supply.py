"""Programmable DC supply over SCPI on any VISA resource: the `scpi` family (generic, single
channel) and the driver every SCPI supply family shares.

A family differs only in its command strings (`ScpiDialect`: `drivers.keysight_e36300`,
`drivers.rigol_dp800`); `ScpiSupply` holds the semantics. Every setting is followed by draining
the error queue (see `drivers.scpi.ScpiCommands.setting`), so a refused value raises `ScpiError`
at the command that caused it. A shorted part drives the supply into constant-current mode:
`check_current_limit` (call it after switching the output on and after each voltage change)
sees the output voltage collapse at the current limit and raises `SupplyCurrentLimit`.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator

from drivers.errors import (
    ConnectionLost,
    InstrumentError,
    InstrumentTimeout,
    ProtocolError,
    ScpiError,
    SupplyCurrentLimit,
    WrongInstrument,
)
from drivers.protocols import InstrumentIdentity, OutputRange, SafeReadback
from drivers.scpi import ScpiCommands, ScpiTransport, parse_float
from drivers.visa import VisaTransport, resource_name

log = logging.getLogger(__name__)

NAME = "DC supply"
# constant-current mode: the output sags this far below the set voltage while the current
# sits this close to its limit
CC_VOLTAGE_SAG_V = 0.05
CC_CURRENT_FRACTION = 0.98


# an output's (lowest V, highest V, highest A), by model and output number
ModelOutputs = dict[str, dict[int, tuple[float, float, float]]]


class ScpiDialect:
    """The generic single-channel SCPI command set (IEEE 488.2 + SCPI 1999 source subsystem)."""

    error_query = "SYST:ERR?"

    def output_name(self, model: str) -> str:
        """The output the parts hang on, as a message names it."""
        return f"the {NAME}'s output"

    def model_output(self, model: str) -> tuple[float, float, float] | None:
        """(lowest V, highest V, highest A) of that output on `model`, from the maker's
        documents; None: the family does not know the model (the instrument is asked)."""
        return None

    def range_queries(self) -> tuple[str, str]:
        """The queries of the output's highest voltage and current (SCPI-1999 vol. 1,
        7.2.1.2: MAXimum)."""
        return "VOLT? MAX", "CURR? MAX"

    def set_voltage(self, supply_v: float) -> str:
        return f"VOLT {supply_v:.3f}"

    def set_current_limit(self, current_a: float) -> str:
        return f"CURR {current_a:.4f}"

    def output(self, on: bool) -> str:
        return "OUTP ON" if on else "OUTP OFF"

    def output_query(self) -> str:
        return "OUTP?"

    def measure_voltage(self) -> str:
        return "MEAS:VOLT?"

    def measure_current(self) -> str:
        return "MEAS:CURR?"

    def voltage_setting_query(self) -> str:
        return "VOLT?"

    def current_limit_query(self) -> str:
        return "CURR?"


class ScpiSupply:
    """`drivers.protocols.Supply` speaking SCPI over a line transport.

    Args:
        transport: an open line transport (`VisaTransport.open(...)`, or a test stand-in).
        dialect: the family's command strings (default: generic single-channel SCPI).
        name: the instrument's name in messages.
    """

    def __init__(
        self, transport: ScpiTransport, dialect: ScpiDialect | None = None, *, name: str = NAME
    ) -> None:
        self.dialect = dialect or ScpiDialect()
        self.name = name
        self._scpi = ScpiCommands(transport, error_query=self.dialect.error_query)
        self._voltage_set_v: float | None = None
        self._current_limit_a: float | None = None
        # the supply's rating (station.yaml max_voltage_v / max_current_a), for the pre-flight
        self.limits: tuple[float | None, float | None] = (None, None)
        # opens the transport again at a reply timeout (wall s): set by `open`; None for a
        # transport handed in, which this driver cannot reopen
        self._reopen: Callable[[float | None], ScpiTransport] | None = None
        # who *IDN? first said it is: a reconnect commands nothing until it says so again
        self._identity: InstrumentIdentity | None = None
        # station.yaml's expected_model: the model when *IDN?'s is not one the family knows
        self.configured_model = ""

    @classmethod
    def open(
        cls,
        address: str,
        *,
        baudrate: int = 115200,
        timeout_s: float = 1.0,
        dialect: ScpiDialect | None = None,
        name: str = NAME,
    ) -> ScpiSupply:
        """Open a VISA resource string, a serial device path or host:port (`drivers.visa`)."""
        current = {"timeout_s": timeout_s}

        def reopen(new_timeout_s: float | None) -> ScpiTransport:
            if new_timeout_s is not None:
                current["timeout_s"] = new_timeout_s
            return VisaTransport.open(
                address, baud=baudrate, timeout_s=current["timeout_s"], instrument=name
            )

        supply = cls(reopen(None), dialect, name=name)
        supply._reopen = reopen
        return supply

    def reconnect(self, timeout_s: float | None = None) -> None:
        """Close the connection and open a new one, with a new reply timeout (wall s) if
        given: the safe-state pass's way through to a slow or re-plugged supply."""
        if self._reopen is None:
            raise ConnectionLost(
                f"the {self.name} was opened over a given transport and cannot reconnect",
                instrument=self.name,
            )
        self._scpi.close()  # VisaTransport.close logs, never raises: the old link may be dead
        self._scpi = ScpiCommands(self._reopen(timeout_s), error_query=self.dialect.error_query)
        self._check_same_supply()

    def _check_same_supply(self) -> None:
        """The address may lead to another device now (an adapter re-enumerated, a
        pseudo-terminal number given to another program): WrongInstrument, the port closed
        again and nothing commanded, unless *IDN? names the supply first identified."""
        known = self._identity
        if known is None:
            return
        try:
            found = self._ask_identity()
        except InstrumentError as exc:
            self._scpi.close()
            raise WrongInstrument(
                f"the {self.name}'s address no longer answers *IDN? as the supply ({exc}); "
                "nothing was commanded there: switch the supply off at its front panel and "
                "check which device the address names",
                instrument=self.name,
            ) from None
        if _who(found) != _who(known):
            self._scpi.close()
            raise WrongInstrument(
                f"the {self.name}'s address now answers as {', '.join(_who(found))}, not the "
                f"{', '.join(_who(known))} first opened; nothing was commanded there: switch the "
                "supply off at its front panel and check which device the address names",
                instrument=self.name,
            )

    def identify(self) -> InstrumentIdentity:
        identity = self._ask_identity()
        if self._identity is None:
            self._identity = identity
        return identity

    def _ask_identity(self) -> InstrumentIdentity:
        reply = self._scpi.query("*IDN?")
        fields = [f.strip() for f in reply.split(",")]
        if len(fields) != 4:
            raise ProtocolError(
                f"*IDN? answered {reply!r}, not 'maker,model,serial,firmware': is this port "
                "really the supply?",
                instrument=self.name,
            )
        return InstrumentIdentity(*fields)

    def reset(self) -> None:
        self._scpi.setting("*RST")
        self._voltage_set_v = None
        self._current_limit_a = None

    def set_voltage(self, supply_v: float) -> None:
        if not 0 <= supply_v < 1000:
            raise ValueError(f"supply voltage must be 0..1000 V, got {supply_v!r}")
        self._scpi.setting(self.dialect.set_voltage(supply_v))
        self._voltage_set_v = round(supply_v, 3)

    def set_current_limit(self, current_a: float) -> None:
        if not 0 < current_a < 100:
            raise ValueError(f"current limit must be 0..100 A, got {current_a!r}")
        self._scpi.setting(self.dialect.set_current_limit(current_a))
        self._current_limit_a = round(current_a, 4)

    def output(self, on: bool) -> None:
        self._scpi.setting(self.dialect.output(on))

    def output_is_on(self) -> bool:
        command = self.dialect.output_query()
        reply = self._scpi.query(command).strip().upper()
        if reply in ("1", "ON"):
            return True
        if reply in ("0", "OFF"):
            return False
        raise ProtocolError(
            f"{command} answered {reply!r}, not 1/ON or 0/OFF", instrument=self.name
        )

    def measure_voltage(self) -> float:
        return self._float(self.dialect.measure_voltage())

    def measure_current(self) -> float:
        return self._float(self.dialect.measure_current())

    def _float(self, command: str) -> float:
        return parse_float(self._scpi.query(command), command)

    def check_errors(self) -> None:
        found = self._scpi.errors()
        if found:
            code, text = found[0]
            raise ScpiError(
                f"the {self.name} reports error {code} {text}", code=code, instrument=self.name
            )

    def check_current_limit(self) -> tuple[float, float]:
        """Measure (volts, amps); raise SupplyCurrentLimit if the supply is current-limiting."""
        if self._voltage_set_v is None:
            self._voltage_set_v = self._float(self.dialect.voltage_setting_query())
        if self._current_limit_a is None:
            self._current_limit_a = self._float(self.dialect.current_limit_query())
        volts = self.measure_voltage()
        amps = self.measure_current()
        sagging = volts < self._voltage_set_v - CC_VOLTAGE_SAG_V
        limiting = amps >= CC_CURRENT_FRACTION * self._current_limit_a
        if sagging and limiting:
            raise SupplyCurrentLimit(
                f"the {self.name} is current-limiting: {volts:.3f} V at {amps:.4f} A against "
                f"{self._voltage_set_v:.3f} V set and a {self._current_limit_a:.4f} A limit; "
                "a part or the fixture is probably shorted: switch off, remove the part and "
                "inspect it",
                instrument=self.name,
            )
        return volts, amps

    def output_limits(self) -> tuple[float | None, float | None]:
        """(highest voltage V, highest current limit A) it can set; None: not known."""
        found = self.output_range()
        if found is None:
            return self.limits
        return (found.high_v if found.high_v != INFINITE else None,
                found.max_a if found.max_a != INFINITE else None)

    def output_range(self) -> OutputRange | None:
        """The range of the parts' output: the model's (from *IDN?, or station.yaml's
        expected_model), else what the instrument answers to the range queries, narrowed by
        station.yaml's max_voltage_v / max_current_a; None when nothing tells it."""
        found = self._model_range() or self._asked_range()
        return _narrowed(found, self.limits, self.dialect.output_name(self._model_name()))

    def _model_name(self) -> str:
        return (self._identity or self.identify()).model

    def _model_range(self) -> OutputRange | None:
        for model in (self._model_name(), self.configured_model):
            found = self.dialect.model_output(model) if model else None
            if found is not None:
                low, high, amps = found
                return OutputRange(self.dialect.output_name(model), low, high, amps,
                                   f"the {model}'s rating")
        return None

    def _asked_range(self) -> OutputRange | None:
        volts_q, amps_q = self.dialect.range_queries()
        try:
            volts, amps = self._float(volts_q), self._float(amps_q)
        except (InstrumentTimeout, ProtocolError) as exc:
            log.info("the %s does not tell its range (%s): %s", self.name, volts_q, exc)
            try:
                self._scpi.errors()  # whatever the refusal queued
            except InstrumentError as drain:
                log.info("draining the %s's errors: %s", self.name, drain)
            return None
        return OutputRange(self.dialect.output_name(self._model_name()), min(0.0, volts),
                           max(0.0, volts), amps, f"its {volts_q} and {amps_q}")

    def safe_state(self) -> None:
        try:
            self._scpi.setting(self.dialect.output(False))
        except InstrumentError as exc:
            log.warning("switching the %s off: %s", self.name, exc)
            raise

    def close(self) -> None:
        self._scpi.close()

    # ------------------------------------------------------------ safe-state readback

    def check_safe(self) -> SafeReadback:
        """Read back whether the output is off (OUTP?)."""
        if self.output_is_on():
            return SafeReadback(False, f"output ON, measuring {self.measure_voltage():.3f} V")
        return SafeReadback(True, "output off")


INFINITE = float("inf")


def _narrowed(
    found: OutputRange | None, limits: tuple[float | None, float | None], name: str
) -> OutputRange | None:
    """`found` within station.yaml's max_voltage_v / max_current_a (which may narrow the
    model's range, never widen it)."""
    max_v, max_a = limits
    if found is None:
        if max_v is None and max_a is None:
            return None
        found = OutputRange(name, 0.0, INFINITE, INFINITE, "")
    high = found.high_v if max_v is None else min(found.high_v, max_v)
    amps = found.max_a if max_a is None else min(found.max_a, max_a)
    if (high, amps) == (found.high_v, found.max_a):
        return found
    narrowed = [k for k, v, f in (("max_voltage_v", max_v, found.high_v),
                                  ("max_current_a", max_a, found.max_a))
                if v is not None and v < f]
    source = f"station.yaml's {' and '.join(narrowed)}"
    if found.source:
        source += f" within {found.source}"
    return OutputRange(found.output, found.low_v, high, amps, source)


def _who(identity: InstrumentIdentity) -> tuple[str, str, str]:
    """The part of an identity that names one instrument (the firmware may be updated)."""
    return identity.manufacturer, identity.model, identity.serial


# ---------------------------------------------------------------- configuration


class SupplySettings(BaseModel):
    """What every SCPI supply family's station.yaml entry has (`driver` and
    `calibration_due` are taken off by the station)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    address: str = Field(
        description="a VISA resource string (ASRL/dev/ttyUSB0::INSTR, "
        "TCPIP::192.168.1.20::5025::SOCKET, TCPIP::192.168.1.20::INSTR, USB0::...::INSTR), "
        "a serial device path (/dev/ttyUSB0) or host:port (a raw SCPI socket)",
    )
    timeout_s: float = Field(1.0, gt=0.0, le=60.0, description="reply timeout, wall seconds")
    expected_model: str = Field("", description="if set, *IDN?'s model must contain this")
    max_voltage_v: float | None = Field(
        None, gt=0, le=1000, description="narrows the output's voltage range the pre-flight checks "
        "against (the model's, or VOLT? MAX)"
    )
    max_current_a: float | None = Field(
        None, gt=0, le=100, description="narrows the output's current range the pre-flight checks "
        "against (the model's, or CURR? MAX)"
    )

    @field_validator("address")
    @classmethod
    def _address(cls, value: str) -> str:
        resource_name(value)  # ValueError says which forms are accepted
        return value.strip()


class Settings(SupplySettings):
    """The `supply.scpi` entry of station.yaml."""

    baud: int = Field(115200, ge=300, le=4_000_000, description="serial baud rate (ASRL only)")


def open_checked(
    settings: SupplySettings, dialect: ScpiDialect, *, baud: int, name: str
) -> ScpiSupply:
    """Open a supply family from its validated settings; with `expected_model`, its *IDN?
    must name that model (ProtocolError otherwise, and the connection is closed)."""
    supply = ScpiSupply.open(
        settings.address, baudrate=baud, timeout_s=settings.timeout_s, dialect=dialect, name=name
    )
    supply.limits = (settings.max_voltage_v, settings.max_current_a)
    supply.configured_model = settings.expected_model
    if settings.expected_model:
        try:
            model = supply.identify().model
            if settings.expected_model not in model:
                raise ProtocolError(
                    f"the {name} at {settings.address} says it is a {model!r}, not the "
                    f"expected {settings.expected_model!r}: check the address or expected_model",
                    instrument=name,
                )
        except BaseException:
            supply.close()
            raise
    return supply


def factory(settings: dict[str, Any]) -> ScpiSupply:
    """Entry point `supply.scpi`: validate the settings (ValidationError propagates), connect."""
    s = Settings.model_validate(settings)
    return open_checked(s, ScpiDialect(), baud=s.baud, name=NAME)
