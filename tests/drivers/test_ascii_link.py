"""The CR LF line link over a real TCP socket: the exact bytes sent, a reply split across
segments, a partial reply (timeout), a closed connection, a late reply never taken for the
next answer, and the address forms."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable
from functools import partial

import pytest

from common.address import parse_host_port
from drivers.ascii_link import LineLink, open_port
from drivers.errors import ConnectionLost, InstrumentTimeout
from tests.drivers.expected_protocol import Stream


class ScriptedPeer:
    """Accepts connections; `handler(conn, received_line)` answers each line it receives."""

    def __init__(self, handler: Callable[[socket.socket, bytes], None]) -> None:
        self.lines: list[bytes] = []
        self._handler = handler
        self._sock = socket.create_server(("127.0.0.1", 0))
        self.port = self._sock.getsockname()[1]
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self._sock.accept()
            except OSError:
                return
            threading.Thread(target=self._talk, args=(conn,), daemon=True).start()

    def _talk(self, conn: socket.socket) -> None:
        stream = Stream(conn, threading.Event())
        with conn:
            while (line := stream.read_until(b"\r\n")) is not None:
                self.lines.append(line[:-2])
                self._handler(conn, line[:-2])

    def close(self) -> None:
        self._sock.close()


def link_to(peer: ScriptedPeer, timeout_s: float = 0.3) -> LineLink:
    where = f"127.0.0.1:{peer.port}"
    opener = partial(open_port, where, baudrate=9600, timeout_s=timeout_s)
    return LineLink(opener, instrument="test chamber", where=where, timeout_s=timeout_s)


def test_reply_split_across_segments_is_one_line():
    def answer(conn: socket.socket, line: bytes) -> None:
        conn.sendall(b"24.8,25")
        time.sleep(0.02)
        conn.sendall(b".0,150.0,-70.0\r\n")

    peer = ScriptedPeer(answer)
    link = link_to(peer)
    assert link.query("TEMP?") == "24.8,25.0,150.0,-70.0"
    assert peer.lines == [b"TEMP?"]
    link.close()
    peer.close()


def test_partial_reply_is_a_timeout_and_the_late_rest_is_never_an_answer():
    replies = iter([b"24.8,", b"MODE?-answer\r\n"])

    def answer(conn: socket.socket, line: bytes) -> None:
        if line == b"TEMP?":
            conn.sendall(next(replies))
            time.sleep(0.5)  # the rest comes after the timeout
            conn.sendall(b"25.0,150.0,-70.0\r\n")
        else:
            conn.sendall(next(replies))

    peer = ScriptedPeer(answer)
    link = link_to(peer)
    with pytest.raises(InstrumentTimeout, match=r"only b'24.8,' arrived"):
        link.query("TEMP?")
    time.sleep(0.6)
    assert link.query("MODE?") == "MODE?-answer"  # a new connection: the late bytes are gone
    link.close()
    peer.close()


def test_closed_connection_is_connection_lost_and_the_next_query_reconnects():
    calls = []

    def answer(conn: socket.socket, line: bytes) -> None:
        calls.append(line)
        if len(calls) == 1:
            conn.shutdown(socket.SHUT_RDWR)
        else:
            conn.sendall(b"CONSTANT\r\n")

    peer = ScriptedPeer(answer)
    link = link_to(peer)
    with pytest.raises(ConnectionLost, match="dropped during 'MODE\\?'"):
        link.query("MODE?")
    assert link.query("MODE?") == "CONSTANT"
    link.close()
    peer.close()


def test_nothing_listening_is_connection_lost():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(ConnectionLost, match="cannot open"):
        open_port(f"127.0.0.1:{port}", baudrate=9600, timeout_s=0.3)


@pytest.mark.parametrize(
    ("address", "expected"),
    [
        ("192.168.0.30:10001", ("192.168.0.30", 10001)),
        ("chamber-3.lab:502", ("chamber-3.lab", 502)),
        ("[::1]:10001", ("::1", 10001)),
        ("/dev/ttyUSB0", None),
        ("10.0.0.1:0", None),
        ("10.0.0.1:70000", None),
        ("10.0.0.1", None),
    ],
)
def test_host_port_form(address, expected):
    assert parse_host_port(address) == expected


def test_one_host_port_form_for_every_tcp_address() -> None:
    """Issue 27: one parser (common/address.py) for the tables, chambers, inclinometers, the
    bench's control channel and the operator relay; the refusal names the form."""
    from common.address import split_host_port
    from drivers.sim.control_client import ControlClient
    from station.prompt_relay import PromptRelay

    assert split_host_port(" [fe80::1]:502 ") == ("fe80::1", 502)
    for bad in ("127.0.0.1", "host name:502", "h:0", "/dev/ttyUSB0"):
        with pytest.raises(ValueError, match="is not host:port"):
            split_host_port(bad)
        with pytest.raises(ValueError, match="is not host:port"):
            PromptRelay(bad)
        with pytest.raises(ValueError, match="is not host:port"):
            ControlClient(bad)
