"""`--sim` never reaches past the simulated bench: a role station.yaml names that the bench
does not serve is refused before any connection, in one line naming the role and the sim
config key that would serve it; no socket of the station connects outside 127.0.0.0/8.

In-process, with the socket layer watched: every connect of the test process (the station's
drivers, asyncio, pyvisa, pymodbus) goes through `socket.socket.connect`/`connect_ex`.
"""

from __future__ import annotations

import ipaddress
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from station.cli.main import main

ROOT = Path(__file__).resolve().parents[2]
SHORT = ROOT / "tests/procedures/data/short.yaml"
DOC_ADDRESS = "192.0.2.1"  # TEST-NET-1 (RFC 5737): never a real host


def _outside_loopback(address: object) -> str | None:
    """The host of an AF_INET/AF_INET6 address outside loopback; None for loopback or AF_UNIX."""
    if not isinstance(address, tuple):
        return None  # a Unix socket path
    host = str(address[0])
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        return host  # a name: only loopback addresses are allowed
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped
    return None if ip.is_loopback else host


@pytest.fixture
def outside() -> Iterator[list[str]]:
    """Every attempt of this process to connect outside loopback, each refused at once."""
    attempts: list[str] = []
    real_connect, real_connect_ex = socket.socket.connect, socket.socket.connect_ex

    def connect(self: socket.socket, address: object) -> None:
        if (host := _outside_loopback(address)) is not None:
            attempts.append(host)
            raise ConnectionRefusedError(f"test: no connection outside loopback ({host})")
        real_connect(self, address)  # type: ignore[arg-type]

    def connect_ex(self: socket.socket, address: object) -> int:
        if (host := _outside_loopback(address)) is not None:
            attempts.append(host)
            return 111
        return real_connect_ex(self, address)  # type: ignore[arg-type]

    mp = pytest.MonkeyPatch()
    mp.setattr(socket.socket, "connect", connect)
    mp.setattr(socket.socket, "connect_ex", connect_ex)
    try:
        yield attempts
    finally:
        mp.undo()


def test_the_watch_catches_a_connection_outside_loopback(outside: list[str]) -> None:
    """The watch itself: a connection to the documentation address is seen (and refused)."""
    with pytest.raises(OSError):
        socket.create_connection((DOC_ADDRESS, 4001), timeout=0.5)
    assert outside == [DOC_ADDRESS]


def test_a_role_the_bench_does_not_serve_is_refused_before_any_connection(
    tmp_path: Path, outside: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    yaml = tmp_path / "station.yaml"
    yaml.write_text(
        (ROOT / "config/station.yaml").read_text().replace("output_folder: ../runs\n", "")
        .replace("results_db: ../runs/results.sqlite\n", "")
        .replace("procedure: procedures/", f"procedure: {ROOT}/config/procedures/")
        + f"  inclinometer:\n    driver: inclinometer.ascii-xy\n"
        f"    ports: {{1: {DOC_ADDRESS}:4001}}\n"
    )
    out = tmp_path / "out"
    code = main([
        "run", "--sim", "--station", str(yaml), "--dut", "SIM-0001", "--procedure", str(SHORT),
        "--out", str(out),
    ])  # fmt: skip
    err = capsys.readouterr().err
    assert outside == [], f"connected outside loopback: {outside}"
    assert code == 2, err
    (line,) = err.strip().splitlines()
    line_no = yaml.read_text().splitlines().index("  inclinometer:") + 1
    assert line.startswith(f"station run: error: {yaml}:{line_no}: "), line
    assert "the inclinometer" in line and "does not serve it" in line
    assert "instruments.inclinometer: ascii-xy in the sim config" in line
    assert not any(out.rglob("record.json"))
