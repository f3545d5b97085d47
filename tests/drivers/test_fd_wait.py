"""Instrument links whose descriptors are above 1024 (FD_SETSIZE): issue 25 finding 8, the
fixture reader logging "filedescriptor out of range in select()" once the operator screen
held a thousand idle connections, and the rate table's link looking dropped.

The low descriptors are taken first, so every link opened in a test lands above 1024; each
transport the station drives instruments with then has to wait without `select.select()`:
pyserial (the fixture's ports), pymodbus (tables and chambers), pyvisa-py (SCPI sockets).
"""

from __future__ import annotations

import errno
import os
import resource
import socket
from collections.abc import Iterator

import pytest

from drivers import keysight_e36300, watlow_f4t
from drivers.fd_wait import LIBRARY_MODULES, select_by_poll, use_poll
from drivers.scpi import open_serial
from drivers.sim.scpi_lan_twins import KeysightE36300Twin
from drivers.sim.watlow_f4t_twin import WatlowF4TTwin
from tests.drivers._chamber_twin_thread import TwinThread

FD_SETSIZE = 1024
HIGH = 1100  # descriptors held open: every new one lands above FD_SETSIZE


@pytest.fixture
def high_fds() -> Iterator[None]:
    """Raise the soft descriptor limit if needed and hold the low descriptors open."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    need = HIGH + 200
    if hard != resource.RLIM_INFINITY and hard < need:
        pytest.skip(f"the descriptor limit ({hard}) is below {need}: cannot reach past 1024")
    if soft != resource.RLIM_INFINITY and soft < need:
        resource.setrlimit(resource.RLIMIT_NOFILE, (need, hard))
    held = []
    try:
        while True:
            fd = os.open(os.devnull, os.O_RDONLY)
            held.append(fd)
            if fd >= HIGH:
                break
        yield
    finally:
        for fd in held:
            os.close(fd)
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


def test_select_by_poll_keeps_selects_answers_above_1024(high_fds: None) -> None:
    a, b = socket.socketpair()
    try:
        assert a.fileno() > FD_SETSIZE
        assert select_by_poll([a], [], [], 0.01) == ([], [], [])
        assert select_by_poll([], [a], [], 0.01) == ([], [a], [])
        b.send(b"x")
        assert select_by_poll([a, b.fileno()], [], [], 1.0) == ([a], [], [])
        b.close()
        r, _, _ = select_by_poll([a], [], [], 1.0)  # the peer gone: readable (EOF), as select
        assert r == [a] and a.recv(10) == b"x" and a.recv(10) == b""
        dead = os.dup(a.fileno())
        os.close(dead)
        with pytest.raises(OSError) as err:
            select_by_poll([dead], [], [], 0.0)
        assert err.value.errno == errno.EBADF
    finally:
        a.close()
        b.close()


def test_every_library_that_waits_with_select_gets_poll() -> None:
    assert set(use_poll()) >= {"serial.serialposix", "pyvisa_py.tcpip", "pymodbus.client.tcp"}
    import importlib

    for name in LIBRARY_MODULES:
        module = importlib.import_module(name)
        assert module.select.select is select_by_poll, name
        assert module.select.poll is not None and module.select.error is OSError


def test_fixture_port_reads_and_writes_above_1024(high_fds: None) -> None:
    """The fixture's serial link (pyserial on a pseudo-terminal), as the part link opens it."""
    master, slave = os.openpty()
    port = open_serial(os.ttyname(slave), read_timeout_s=0.2)
    try:
        assert port.fileno() > FD_SETSIZE
        os.write(master, b"FRAME\n")
        assert port.read(6) == b"FRAME\n"
        assert port.read(1) == b""  # the read timeout, not an error
        port.write(b"STOP\r\n")
        assert os.read(master, 6) == b"STOP\r\n"
    finally:
        port.close()
        os.close(master)
        os.close(slave)


def test_modbus_chamber_above_1024(high_fds: None) -> None:
    with TwinThread(WatlowF4TTwin) as tt:
        chamber = watlow_f4t.factory({"address": tt.endpoint, "timeout_s": 1.0})
        try:
            assert chamber._link._client.socket.fileno() > FD_SETSIZE  # type: ignore[attr-defined]
            assert chamber.read_temperature() == pytest.approx(25.0, abs=0.5)
            chamber.safe_state(25.0)
            assert chamber.check_safe(25.0).safe
        finally:
            chamber.close()


def test_scpi_supply_over_a_visa_socket_above_1024(high_fds: None) -> None:
    with TwinThread(KeysightE36300Twin) as tt:
        supply = keysight_e36300.factory({"address": tt.endpoint, "timeout_s": 1.0})
        try:
            sock = supply._scpi.transport._socket()  # type: ignore[attr-defined]
            assert sock is not None and sock.fileno() > FD_SETSIZE
            assert supply.identify().model
            supply.output(True)
            assert supply.output_is_on()
            supply.safe_state()
            assert supply.check_safe().safe
        finally:
            supply.close()


def test_no_select_select_call_in_the_product() -> None:
    """The station's own code never calls select.select() (FD_SETSIZE): poll or selectors."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    found = []
    for package in ("drivers", "station", "procedures", "reports"):
        for path in (root / package).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                func = getattr(node, "func", None)
                if (
                    isinstance(node, ast.Call)
                    and isinstance(func, ast.Attribute)
                    and func.attr == "select"
                    and isinstance(func.value, ast.Name)
                    and func.value.id in ("select", "_select")
                ):
                    found.append(f"{path.relative_to(root)}:{node.lineno}")
    assert found == []
