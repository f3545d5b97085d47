"""The VISA transport (pyvisa + pyvisa-py): address forms, and every link failure as a typed
exception (never a raw OSError, termios.error or VisaIOError), over real sockets and ptys."""

from __future__ import annotations

import re
import socket
import time

import pytest

from drivers.errors import ConnectionLost, InstrumentError, InstrumentTimeout
from drivers.visa import VisaTransport, resource_name
from tests.drivers._scpi_fakes import ScriptedScpi
from tests.drivers.expected_protocol import Pair

KINDS = ["tcp", "pty"]


@pytest.mark.parametrize(
    "address, expected",
    [
        ("/dev/ttyUSB0", "ASRL/dev/ttyUSB0::INSTR"),
        ("/dev/pts/5", "ASRL/dev/pts/5::INSTR"),
        ("COM3", "ASRL3::INSTR"),
        ("ASRL/dev/pts/5::INSTR", "ASRL/dev/pts/5::INSTR"),
        ("TCPIP::192.168.1.20::5025::SOCKET", "TCPIP::192.168.1.20::5025::SOCKET"),
        ("TCPIP0::192.168.1.20::inst0::INSTR", "TCPIP0::192.168.1.20::inst0::INSTR"),
        ("USB0::0x2A8D::0x1102::MY5900::0::INSTR", "USB0::0x2A8D::0x1102::MY5900::0::INSTR"),
        ("psu.lab:5025", "TCPIP::psu.lab::5025::SOCKET"),
    ],
)
def test_resource_name_forms(address: str, expected: str) -> None:
    assert resource_name(address) == expected


def test_resource_name_refuses_anything_else() -> None:
    with pytest.raises(ValueError, match="neither a VISA resource string"):
        resource_name("supply on the left")


def _open(fake: ScriptedScpi, timeout_s: float = 0.3) -> VisaTransport:
    return VisaTransport.open(fake.resource, timeout_s=timeout_s, instrument="supply")


@pytest.mark.parametrize("kind", KINDS)
def test_no_reply_and_a_partial_reply_are_timeouts(kind: str) -> None:
    fake = ScriptedScpi([Pair(b"MEAS:VOLT?\n"), Pair(b"MEAS:CURR?\n", b"0.02")], kind)
    link = _open(fake, timeout_s=0.2)
    try:
        for command in ("MEAS:VOLT?", "MEAS:CURR?"):
            t0 = time.monotonic()
            expected = re.escape(f"did not answer '{command}' within 0.2 s")
            with pytest.raises(InstrumentTimeout, match=expected):
                link.query(command)
            assert 0.15 <= time.monotonic() - t0 < 1.5
    finally:
        link.close()
        fake.close()
    fake.assert_done()


@pytest.mark.parametrize("kind", KINDS)
def test_late_reply_to_a_timed_out_query_does_not_answer_the_next(kind: str) -> None:
    fake = ScriptedScpi(
        [Pair(b"MEAS:VOLT?\n", b"4.0000\n", delay_s=0.3), Pair(b"MEAS:CURR?\n", b"0.020000\n")],
        kind,
    )
    link = _open(fake, timeout_s=0.15)
    try:
        with pytest.raises(InstrumentTimeout):
            link.query("MEAS:VOLT?")
        time.sleep(0.3)  # the stale "4.0000" is now waiting in the input
        assert link.query("MEAS:CURR?") == "0.020000"
    finally:
        link.close()
        fake.close()
    fake.assert_done()


@pytest.mark.parametrize("kind", KINDS)
def test_link_dying_during_a_query_is_connection_lost(kind: str) -> None:
    fake = ScriptedScpi([Pair(b"*IDN?\n", b"A,B,C,D\n"), Pair(b"MEAS:VOLT?\n", close=True)], kind)
    link = _open(fake, timeout_s=0.5)
    try:
        assert link.query("*IDN?") == "A,B,C,D"
        with pytest.raises(ConnectionLost) as info:
            link.query("MEAS:VOLT?")
        # and every later exchange says so too, typed (a pty's tcflush raised termios.error)
        with pytest.raises(ConnectionLost):
            link.write("OUTP OFF")
    finally:
        link.close()
        fake.close()
    assert "supply" in str(info.value)
    assert not isinstance(info.value.__cause__, InstrumentError)


def test_socket_closed_while_idle_is_connection_lost_before_anything_is_sent() -> None:
    fake = ScriptedScpi([Pair(b"*IDN?\n", b"A,B,C,D\n"), Pair(b"*CLS\n", close=True)])
    link = _open(fake, timeout_s=2.0)
    try:
        link.query("*IDN?")
        link.write("*CLS")  # the instrument hangs up after this one
        time.sleep(0.1)
        t0 = time.monotonic()
        with pytest.raises(ConnectionLost, match="closed the connection"):
            link.query("*IDN?")
        assert time.monotonic() - t0 < 0.5  # not after the 2 s timeout
    finally:
        link.close()
        fake.close()


def test_open_failures_are_connection_lost_with_what_to_do() -> None:
    with socket.socket() as probe:  # a port nobody listens on
        probe.bind(("127.0.0.1", 0))
        free_port = probe.getsockname()[1]
    cases = {
        "/dev/ttyDOES-NOT-EXIST": "check the port name",
        f"TCPIP::127.0.0.1::{free_port}::SOCKET": "reachable",
        "TCPIP::127.0.0.1::INSTR": "reachable",  # VXI-11: no portmapper here
        "USB0::0x2A8D::0x1102::MY59001234::0::INSTR": "pyusb",
    }
    for address, advice in cases.items():
        with pytest.raises(ConnectionLost, match=advice):
            VisaTransport.open(address, timeout_s=0.3, instrument="supply")


def test_a_closed_transport_refuses_politely() -> None:
    fake = ScriptedScpi([])
    link = _open(fake)
    link.close()
    link.close()  # idempotent
    try:
        with pytest.raises(ConnectionLost, match="is closed"):
            link.query("*IDN?")
    finally:
        fake.close()


def test_socket_sends_without_waiting_for_a_delayed_ack() -> None:
    """A setting and its SYST:ERR? are two small writes in a row: with Nagle on, the second
    waits for the instrument's delayed ACK (40 ms on Linux) on every setting."""
    fake = ScriptedScpi([])
    link = _open(fake)
    try:
        sock = link._socket()
        assert sock is not None
        assert sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) != 0
    finally:
        link.close()
        fake.close()
