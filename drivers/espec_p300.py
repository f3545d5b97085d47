"""ESPEC P-300 chamber controller: CR LF terminated ASCII commands over TCP or a serial port.

The commands used (ESPEC's P-300 communication manual; ESPEC's ChamberConnectLibrary uses the
same set):

| command | reply |
| --- | --- |
| `TEMP?` | `<pv>,<setpoint>,<upper limit>,<lower limit>` in C |
| `MON?` | `<pv>,<humidity or empty>,<mode>,<number of active alarms>` |
| `MODE?` | `OFF`, `STANDBY`, `CONSTANT` or `RUN` |
| `ALARM?` | `<count>[,<code>...]` |
| `ROM?` / `TYPE?` | firmware / `<sensor>[,<wet sensor>],<controller>,<max temperature>` |
| `TEMP, S25.0` / `MODE, CONSTANT` / `MODE, STANDBY` / `POWER,ON` / `POWER,OFF` | `OK:<command>` |

A refused command is answered `NA:<reason>`; `NA_ERRORS` maps each reason to the typed
exception it raises. The P-300 works in C. Constant mode has no ramp rate, so the ramp is done
by this driver (`drivers.ramped_chamber`). A chamber fault is a nonzero alarm count in `MON?`:
`wait_setpoint` raises `ChamberAlarm` with the codes from `ALARM?`.
"""

from __future__ import annotations

import logging
import re
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator

from common.address import parse_host_port
from common.clock import Clock
from drivers.ascii_link import LineLink, LinePort, open_port
from drivers.errors import ChamberRefused, InstrumentError, ProtocolError, SetpointOutOfRange
from drivers.protocols import InstrumentIdentity
from drivers.ramped_chamber import RampedChamber

log = logging.getLogger(__name__)

NAME = "ESPEC P-300 chamber controller"
DEFAULT_TCP_PORT = 10001
RUNNING_MODES = frozenset({"CONSTANT", "RUN"})

# NA:<reason> -> (exception class, what to do)
NA_ERRORS: dict[str, tuple[type[InstrumentError], str]] = {
    "DATA OUT OF RANGE": (SetpointOutOfRange, "the value is outside the controller's limits"),
    "PROTECT ON": (ChamberRefused, "turn data protection off at the controller's panel"),
    "CHB NOT READY": (ChamberRefused, "the chamber cannot act now: check its panel"),
    "CONT NOT READY-1": (ChamberRefused, "this chamber has no humidity/PTC control"),
    "CONT NOT READY-2": (ChamberRefused, "the chamber is not running a program"),
    "CONT NOT READY-3": (ProtocolError, "this controller does not support the command"),
    "CMD ERR": (ProtocolError, "the controller does not know the command: is it a P-300?"),
    "PARA ERR": (ProtocolError, "a parameter is missing or not understood"),
    "ADDR ERR": (ProtocolError, "bad address: check the controller's communication setup"),
    "INVALID REQ": (ProtocolError, "the controller does not support this request"),
}
_SERIAL_PATH = re.compile(r"^(/\S+|COM\d+|[a-z0-9+]+://\S+)$")  # device path or pyserial URL


class Settings(BaseModel):
    """station.yaml `instruments.chamber` for `driver: espec-p300`."""

    model_config = ConfigDict(extra="forbid")

    address: str = Field(
        description="host:port (the P-300's LAN port is 10001) or a serial device path"
    )
    timeout_s: float = Field(2.0, gt=0.0, le=60.0, allow_inf_nan=False)
    poll_s: float = Field(1.0, gt=0.0, le=600.0, allow_inf_nan=False)
    baudrate: int = Field(9600, description="serial only: 4800, 9600 or 19200")
    serial: str = Field("", max_length=40, description="nameplate serial (not on the wire)")

    @field_validator("address")
    @classmethod
    def _address(cls, address: str) -> str:
        if parse_host_port(address) is None and _SERIAL_PATH.match(address) is None:
            raise ValueError(
                "address must be host:port (e.g. 192.168.0.30:10001) or a serial device "
                f"path (e.g. /dev/ttyUSB0), got {address!r}"
            )
        return address

    @field_validator("baudrate")
    @classmethod
    def _baud(cls, baudrate: int) -> int:
        if baudrate not in (4800, 9600, 19200):
            raise ValueError(f"baudrate must be 4800, 9600 or 19200, got {baudrate}")
        return baudrate


def factory(settings: dict[str, Any]) -> EspecP300:
    """Validate `settings`, connect and return the driver (station clock: `attach_clock`)."""
    cfg = Settings.model_validate(settings)

    def opener() -> LinePort:  # at the link's timeout now: `reconnect` may have lengthened it
        return open_port(cfg.address, baudrate=cfg.baudrate, timeout_s=link.timeout_s)

    link = LineLink(opener, instrument=NAME, where=cfg.address, timeout_s=cfg.timeout_s)
    link.connect()
    return EspecP300(link, poll_s=cfg.poll_s, serial=cfg.serial)


def link_over(port: LinePort, *, timeout_s: float = 1.0, where: str = "(port)") -> LineLink:
    """A link over an already open port (tests, or a port opened by the caller)."""
    return LineLink(lambda: port, instrument=NAME, where=where, timeout_s=timeout_s)


def _number(text: str, command: str, reply: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise ProtocolError(
            f"the {NAME} answered {command!r} with {reply!r}, which does not parse as "
            "numbers: is this a P-300 at that address?",
            instrument=NAME,
        ) from None


class EspecP300(RampedChamber):
    """`drivers.protocols.Chamber` for an ESPEC P-300.

    Args:
        link: the command/reply link to the controller.
        clock: the station clock (default `ScaledClock(1.0)` until `attach_clock`).
        poll_s: station seconds between polls while waiting for the setpoint.
        serial: the chamber's serial number for the certificate (the P-300 does not report it).
    """

    def __init__(
        self, link: LineLink, clock: Clock | None = None, *, poll_s: float = 1.0, serial: str = ""
    ) -> None:
        super().__init__(NAME, clock, poll_s=poll_s)
        self._link = link
        self._serial = serial

    # ------------------------------------------------------------ the command language

    def query(self, command: str) -> str:
        """Send one command; its reply, or the typed exception for an `NA:` answer."""
        reply = self._link.query(command)
        if reply.startswith("NA:"):
            reason = reply[3:].strip()
            cls, hint = NA_ERRORS.get(
                reason, (ProtocolError, "see the P-300 manual's error list")
            )
            raise cls(f"the {NAME} refused {command!r}: {reason} ({hint})", instrument=NAME)
        return reply

    def command(self, command: str) -> None:
        """A setting: the controller must answer `OK:` (then the command)."""
        reply = self.query(command)
        if not reply.startswith("OK:"):
            raise ProtocolError(
                f"the {NAME} answered {command!r} with {reply!r} instead of 'OK:...'",
                instrument=NAME,
            )

    def _fields(self, command: str, count: int) -> list[str]:
        reply = self.query(command)
        fields = [f.strip() for f in reply.split(",")]
        if len(fields) < count:
            raise ProtocolError(
                f"the {NAME} answered {command!r} with {reply!r}: expected {count} fields",
                instrument=NAME,
            )
        return fields

    def _temp(self) -> list[float]:
        """TEMP?: [pv, setpoint, upper limit, lower limit]."""
        fields = self._fields("TEMP?", 4)
        return [_number(f, "TEMP?", ",".join(fields)) for f in fields[:4]]

    def mode(self) -> str:
        return self.query("MODE?").strip().upper()

    def identify(self) -> InstrumentIdentity:
        rom = self.query("ROM?").strip()
        kind = [f.strip() for f in self.query("TYPE?").split(",")]
        controller = kind[-2] if len(kind) >= 3 else "P-300"
        return InstrumentIdentity(
            manufacturer="ESPEC", model=controller, serial=self._serial, firmware=rom
        )

    # ------------------------------------------------------------ wire primitives

    def _read_limits(self) -> tuple[float, float]:
        _, _, upper, lower = self._temp()
        return lower, upper

    def _write_setpoint(self, temp_c: float) -> None:
        self.command(f"TEMP, S{temp_c:.1f}")

    def _read_wire_setpoint(self) -> float:
        return self._temp()[1]

    def _read_pv(self) -> float:
        return self._temp()[0]

    def _start(self) -> None:
        mode = self.mode()
        if mode == "OFF":
            self.command("POWER,ON")  # the controller comes up in constant mode
            mode = self.mode()
        if mode != "CONSTANT":
            self.command("MODE, CONSTANT")

    def _standby(self) -> None:
        if self.mode() != "OFF":
            self.command("MODE, STANDBY")

    def _running(self) -> bool:
        return self.mode().split(" ")[0] in RUNNING_MODES

    def _alarms(self) -> list[str]:
        fields = self._fields("MON?", 4)
        count = _number(fields[3], "MON?", ",".join(fields))
        if count <= 0:
            return []
        codes = [f.strip() for f in self.query("ALARM?").split(",")[1:] if f.strip()]
        return [f"alarm code {c}" for c in codes] or [f"{count:g} alarm(s)"]

    def power_off(self) -> None:
        """Switch the controller off (POWER,OFF); run() powers it on again."""
        self.command("POWER,OFF")

    def reconnect(self, timeout_s: float | None = None) -> None:
        self._link.reopen(timeout_s)

    def close(self) -> None:
        self._link.close()
