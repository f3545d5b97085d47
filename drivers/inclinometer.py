"""`inclinometer.ascii-xy`: dual-axis ASCII inclinometers in query mode, one per fixture socket.

The command set is that of many RS-232 dual-axis inclinometers in polling mode (BEI Sensors'
AGS series, for one): `R` reads both axes once, answered by two lines `X=+xx.xxx` and
`Y=-xx.xxx` (degrees, three decimals); `V` reads the sensor type and serial number, answered
by two lines (`AGS360-2-S1`, `SN:1234-567`). Each socket's sensor sits on its own serial line
behind a serial device server in raw TCP mode (one TCP port per serial port), so the
driver's settings give one `host:port` per socket (`ports`; `address` is socket 1's).

The station reads the inclinometer at each stop of a hand-turned fixture (the manual_stop
step): the travel between two readings is the reference angle of the stop method. The
readings of one axis (`axis`) are taken `readings` times and averaged; the standard
uncertainty of one averaged reading is `u_deg` (the sensor's repeatability, from its
datasheet or its own calibration), which the step combines over the moves.
"""

from __future__ import annotations

import logging
import re
import statistics
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from common.address import split_host_port
from drivers.errors import ProtocolError
from drivers.protocols import InstrumentIdentity
from drivers.tcp_lines import LineLink

log = logging.getLogger(__name__)
NAME = "inclinometer"
_AXIS_LINE = re.compile(r"^([XY])=([+-]\d{1,3}\.\d{1,4})$")
MAX_SOCKETS = 16


class Settings(BaseModel):
    """station.yaml `instruments.inclinometer` (driver: inclinometer.ascii-xy)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    address: str = Field(
        "", description="host:port of socket 1's sensor (its serial device server port)"
    )
    ports: dict[int, str] = Field(
        default_factory=dict,
        max_length=MAX_SOCKETS,
        description="socket -> host:port of that socket's sensor (socket 1 defaults to address)",
    )
    axis: Literal["x", "y"] = Field("x", description="the axis that turns with the fixture")
    readings: int = Field(5, ge=1, le=100, description="readings averaged at each stop")
    u_deg: float = Field(
        0.003, gt=0.0, le=5.0, description="standard uncertainty of one averaged reading, deg"
    )
    timeout_s: float = Field(1.0, gt=0.0, le=60.0, description="wall seconds per reply")

    @field_validator("ports")
    @classmethod
    def _sockets(cls, value: dict[int, str]) -> dict[int, str]:
        if any(not 1 <= k <= MAX_SOCKETS for k in value):
            raise ValueError(f"socket numbers are 1..{MAX_SOCKETS}")
        for address in value.values():
            split_host_port(address)
        return value

    def socket_addresses(self) -> dict[int, str]:
        out = dict(self.ports)
        if self.address and 1 not in out:
            out[1] = self.address
        return out


def factory(settings: dict[str, Any]) -> AsciiInclinometer:
    """The `inclinometer.ascii-xy` driver: validate, connect to every socket's sensor."""
    s = Settings.model_validate(settings)
    addresses = s.socket_addresses()
    if not addresses:
        raise ValueError("give address (socket 1's sensor) or ports: {socket: host:port}")
    links: dict[int, LineLink] = {}
    try:
        for sock, address in sorted(addresses.items()):
            host, port = split_host_port(address)
            link = LineLink(
                host, port, timeout_s=s.timeout_s, instrument=f"inclinometer {sock}",
                send_end=b"\r\n",
            )
            link.connect()
            links[sock] = link
    except BaseException:
        for link in links.values():
            link.close()
        raise
    return AsciiInclinometer(links, axis=s.axis, readings=s.readings, u_deg=s.u_deg)


class AsciiInclinometer:
    """One sensor per socket; `read_angle(socket)` -> (angle deg, standard uncertainty deg)."""

    def __init__(
        self, links: dict[int, LineLink], *, axis: str = "x", readings: int = 5,
        u_deg: float = 0.003,
    ) -> None:
        self.links = links
        self.axis = axis.upper()
        self.readings = readings
        self.u_deg = u_deg

    def _link(self, socket: int) -> LineLink:
        if socket not in self.links:
            raise ProtocolError(
                f"no inclinometer is configured for socket {socket} (sockets "
                f"{', '.join(map(str, sorted(self.links)))}): add it under "
                "instruments.inclinometer.ports in station.yaml",
                instrument=NAME,
            )
        return self.links[socket]

    def _two_lines(self, socket: int, command: str) -> tuple[str, str]:
        link = self._link(socket)
        first = link.query(command)
        second = link.query_more(command)
        return first, second

    def read_axes(self, socket: int) -> dict[str, float]:
        """One `R`: {"X": deg, "Y": deg}; ProtocolError on a reply of another form."""
        lines = self._two_lines(socket, "R")
        out: dict[str, float] = {}
        for line in lines:
            m = _AXIS_LINE.match(line.strip())
            if not m:
                raise ProtocolError(
                    f"inclinometer {socket} answered R with {line!r}, not X=+xx.xxx / "
                    "Y=+xx.xxx: check that it is in polling mode at the configured baud",
                    instrument=NAME,
                )
            out[m.group(1)] = float(m.group(2))
        if set(out) != {"X", "Y"}:
            raise ProtocolError(
                f"inclinometer {socket} answered R without both axes: {lines!r}",
                instrument=NAME,
            )
        return out

    def read_angle(self, socket: int) -> tuple[float, float]:
        """The fixture's angle on the configured axis, `readings` averaged, and its standard
        uncertainty (deg)."""
        values = [self.read_axes(socket)[self.axis] for _ in range(self.readings)]
        return statistics.fmean(values), self.u_deg

    def identify(self) -> InstrumentIdentity:
        first = min(self.links)
        model, serial = self._two_lines(first, "V")
        return InstrumentIdentity(
            manufacturer="", model=model.strip(), serial=serial.strip().removeprefix("SN:")
        )

    def probe(self) -> str:
        for sock in sorted(self.links):
            self.read_axes(sock)
        return ""

    def close(self) -> None:
        for link in self.links.values():
            link.close()
