"""Address forms shared by drivers' settings: `host:port` for TCP instruments."""

from __future__ import annotations


def split_host_port(address: str) -> tuple[str, int]:
    """`host:port` -> (host, port); ValueError saying what is wrong otherwise."""
    host, sep, port = address.strip().rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(
            f"{address!r} is not host:port (for example 192.168.1.20:502 or 127.0.0.1:5020)"
        )
    return host, int(port)


def check_host_port(address: str) -> str:
    """A pydantic validator body: the address unchanged if it is host:port."""
    split_host_port(address)
    return address.strip()
