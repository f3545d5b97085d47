"""The expected-protocol helper itself: it passes an exact exchange and fails any other."""

from __future__ import annotations

import socket
import struct

import pytest

from tests.drivers.expected_protocol import (
    LINES,
    MODBUS,
    Pair,
    SerialPeer,
    TcpPeer,
    expected_protocol,
    finish,
)


def test_an_exact_exchange_passes_and_replies_in_order() -> None:
    port = SerialPeer([(b"A?\n", b"1\n"), (b"B?\n", b"2\n")])
    with expected_protocol(port):
        port.write(b"A?\n")
        assert port.readline() == b"1\n"
        port.write(b"B?\n")
        assert port.readline() == b"2\n"


def test_another_message_fails() -> None:
    port = SerialPeer([(b"A?\n", b"1\n")])
    port.write(b"B?\n")
    with pytest.raises(AssertionError, match=r"expected b'A\?.*got b'B\?"):
        finish(port)


def test_pairs_left_unused_fail() -> None:
    port = SerialPeer([(b"A?\n", b"1\n"), (b"B?\n", b"2\n")])
    port.write(b"A?\n")
    with pytest.raises(AssertionError, match="unused pairs"):
        finish(port)


def test_a_message_after_the_last_pair_fails() -> None:
    port = SerialPeer([])
    port.write(b"A?\n")
    with pytest.raises(AssertionError, match="after the last pair"):
        finish(port)


def test_tcp_lines_and_modbus_framing() -> None:
    lines = TcpPeer([Pair(b"IDN?\r\n", b"X,Y\r\n")], LINES)
    with socket.create_connection(("127.0.0.1", lines.port), timeout=2) as conn:
        conn.sendall(b"IDN?\r\n")
        assert conn.recv(64) == b"X,Y\r\n"
    finish(lines)
    modbus = TcpPeer([Pair(b"\x03\x00\x01\x00\x01", b"\x03\x02\x00\x07")], MODBUS)
    with socket.create_connection(("127.0.0.1", modbus.port), timeout=2) as conn:
        conn.sendall(struct.pack(">HHHB", 9, 0, 6, 1) + b"\x03\x00\x01\x00\x01")
        assert conn.recv(64) == struct.pack(">HHHB", 9, 0, 5, 1) + b"\x03\x02\x00\x07"
    finish(modbus)
