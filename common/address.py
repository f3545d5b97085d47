"""The one `host:port` form of every TCP instrument's address (the Modbus servo tables, the
Acutrol, the chambers, the inclinometers, the ASCII links): a host name, an IPv4 address or
a bracketed IPv6 address, a colon, a port 1..65535."""

from __future__ import annotations

import re

from pydantic import BaseModel, ConfigDict, Field, field_validator

_HOST_PORT = re.compile(r"^(?P<host>[A-Za-z0-9_.\-]+|\[[0-9A-Fa-f:]+\]):(?P<port>\d{1,5})$")


def parse_host_port(address: str) -> tuple[str, int] | None:
    """(host, port) from `host:port` (IPv6 brackets removed), None for any other form (a
    serial device path, a VISA resource)."""
    match = _HOST_PORT.match(address.strip())
    if match is None:
        return None
    port = int(match["port"])
    if not 0 < port < 65536:
        return None
    return match["host"].strip("[]"), port


def split_host_port(address: str) -> tuple[str, int]:
    """`host:port` -> (host, port); ValueError saying the expected form otherwise."""
    found = parse_host_port(address)
    if found is None:
        raise ValueError(
            f"{address!r} is not host:port (for example 192.168.1.20:502, 127.0.0.1:5020 or "
            "[fe80::1]:502)"
        )
    return found


def check_host_port(address: str) -> str:
    """A pydantic validator body: the address unchanged (stripped) if it is host:port."""
    split_host_port(address)
    return address.strip()


class TcpInstrumentSettings(BaseModel):
    """The settings every TCP instrument's driver shares: its `host:port` (checked here), the
    wall seconds it may take per reply, the station seconds between polls in waits. A
    driver's Settings subclasses it, adding its own fields (and its own address
    description)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    address: str = Field(description="host:port of the instrument's TCP interface")
    timeout_s: float = Field(1.0, gt=0, le=60, description="wall seconds per reply")
    poll_s: float = Field(0.05, gt=0, le=5, description="station s between polls in waits")

    @field_validator("address")
    @classmethod
    def _address(cls, v: str) -> str:
        split_host_port(v)
        return v

    def host_port(self) -> tuple[str, int]:
        return split_host_port(self.address)
