"""Programmable DC supply, SCPI over a serial port.

Every setting is followed by draining SYST:ERR? (see `drivers.scpi.ScpiPort.setting`), so a
refused value raises `ScpiError` at the command that caused it. A shorted part drives the
supply into constant-current mode: `check_current_limit` (call it after switching the output
on and after each voltage change) sees the output voltage collapse at the current limit and
raises `SupplyCurrentLimit`.
"""

from __future__ import annotations

import logging
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from drivers.errors import InstrumentError, ProtocolError, ScpiError, SupplyCurrentLimit
from drivers.protocols import InstrumentIdentity
from drivers.scpi import ScpiPort, SerialLike, open_serial, parse_float

log = logging.getLogger(__name__)

NAME = "DC supply"
# constant-current mode: the output sags this far below the set voltage while the current
# sits this close to its limit
CC_VOLTAGE_SAG_V = 0.05
CC_CURRENT_FRACTION = 0.98


class ScpiSupply:
    """`drivers.protocols.Supply` speaking SCPI over a serial port.

    Args:
        port: an open serial port (pyserial `Serial` or a stand-in with its API).
        timeout_s: wall seconds each query waits for its reply.
    """

    def __init__(self, port: SerialLike, *, timeout_s: float = 1.0) -> None:
        self._scpi = ScpiPort(port, timeout_s=timeout_s, instrument=NAME)
        self._voltage_set_v: float | None = None
        self._current_limit_a: float | None = None
        self.limits: tuple[float | None, float | None] = (None, None)

    @classmethod
    def open(cls, path: str, *, baudrate: int = 115200, timeout_s: float = 1.0) -> ScpiSupply:
        return cls(open_serial(path, baudrate=baudrate), timeout_s=timeout_s)

    def identify(self) -> InstrumentIdentity:
        reply = self._scpi.query("*IDN?")
        fields = [f.strip() for f in reply.split(",")]
        if len(fields) != 4:
            raise ProtocolError(
                f"*IDN? answered {reply!r}, not 'maker,model,serial,firmware': is this port "
                "really the supply?",
                instrument=NAME,
            )
        return InstrumentIdentity(*fields)

    def reset(self) -> None:
        self._scpi.setting("*RST")
        self._voltage_set_v = None
        self._current_limit_a = None

    def set_voltage(self, supply_v: float) -> None:
        if not 0 <= supply_v < 1000:
            raise ValueError(f"supply voltage must be 0..1000 V, got {supply_v!r}")
        self._scpi.setting(f"VOLT {supply_v:.3f}")
        self._voltage_set_v = round(supply_v, 3)

    def set_current_limit(self, current_a: float) -> None:
        if not 0 < current_a < 100:
            raise ValueError(f"current limit must be 0..100 A, got {current_a!r}")
        self._scpi.setting(f"CURR {current_a:.4f}")
        self._current_limit_a = round(current_a, 4)

    def output(self, on: bool) -> None:
        self._scpi.setting("OUTP ON" if on else "OUTP OFF")

    def output_is_on(self) -> bool:
        reply = self._scpi.query("OUTP?").strip().upper()
        if reply in ("1", "ON"):
            return True
        if reply in ("0", "OFF"):
            return False
        raise ProtocolError(f"OUTP? answered {reply!r}, not 1 or 0", instrument=NAME)

    def measure_voltage(self) -> float:
        return parse_float(self._scpi.query("MEAS:VOLT?"), "MEAS:VOLT?")

    def measure_current(self) -> float:
        return parse_float(self._scpi.query("MEAS:CURR?"), "MEAS:CURR?")

    def check_errors(self) -> None:
        found = self._scpi.errors()
        if found:
            code, text = found[0]
            raise ScpiError(f"the {NAME} reports error {code} {text}", code=code, instrument=NAME)

    def check_current_limit(self) -> tuple[float, float]:
        """Measure (volts, amps); raise SupplyCurrentLimit if the supply is current-limiting."""
        if self._voltage_set_v is None:
            self._voltage_set_v = parse_float(self._scpi.query("VOLT?"), "VOLT?")
        if self._current_limit_a is None:
            self._current_limit_a = parse_float(self._scpi.query("CURR?"), "CURR?")
        volts = self.measure_voltage()
        amps = self.measure_current()
        sagging = volts < self._voltage_set_v - CC_VOLTAGE_SAG_V
        limiting = amps >= CC_CURRENT_FRACTION * self._current_limit_a
        if sagging and limiting:
            raise SupplyCurrentLimit(
                f"the {NAME} is current-limiting: {volts:.3f} V at {amps:.4f} A against "
                f"{self._voltage_set_v:.3f} V set and a {self._current_limit_a:.4f} A limit; "
                "a part or the fixture is probably shorted: switch off, remove the part and "
                "inspect it",
                instrument=NAME,
            )
        return volts, amps

    def output_limits(self) -> tuple[float | None, float | None]:
        """(highest voltage V, highest current limit A) from station.yaml; None: unknown."""
        return self.limits

    def probe(self) -> str:
        """'' when the supply answers *IDN?."""
        self.identify()
        return ""

    def safe_state(self) -> None:
        try:
            self._scpi.setting("OUTP OFF")
        except InstrumentError as exc:
            log.warning("switching the %s off: %s", NAME, exc)
            raise

    def close(self) -> None:
        self._scpi.close()


# ---------------------------------------------------------------- configuration
# (supply.scpi; minimal, for the registry: the supplies engineer's pyvisa version replaces it)


class Settings(BaseModel):
    """station.yaml `instruments.supply` for `driver: supply.scpi`."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    address: str = Field(min_length=1, description="serial device of the supply")
    baud: int = Field(115200, gt=0, le=10_000_000, description="serial baud rate")
    timeout_s: float = Field(1.0, gt=0, le=60, description="wall seconds per query")
    max_voltage_v: float | None = Field(None, gt=0, le=1000, description="rated output, V")
    max_current_a: float | None = Field(None, gt=0, le=100, description="rated output, A")


def factory(settings: dict[str, Any]) -> ScpiSupply:
    s = Settings.model_validate(settings)
    supply = ScpiSupply.open(s.address, baudrate=s.baud, timeout_s=s.timeout_s)
    supply.limits = (s.max_voltage_v, s.max_current_a)
    return supply
