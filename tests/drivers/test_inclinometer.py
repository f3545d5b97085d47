"""`inclinometer.ascii-xy`: exact bytes on the wire against a scripted server, reply parsing,
averaging, typed errors; and the driver against its twin on the simulated bench."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from drivers import registry
from drivers.errors import ConnectionLost, InstrumentTimeout, ProtocolError
from drivers.inclinometer import AsciiInclinometer, Settings, factory
from drivers.sim.launcher import launch_bench
from drivers.tcp_lines import LineLink
from procedures.runtime.progress import ProgressEvent
from station.prompt_relay import PromptRelay
from tests.drivers.expected_protocol import Pair, TcpPeer
from tests.sim.conftest import wait_until

R = b"R\r\n"


def _make(script: list[Pair], readings: int = 1) -> tuple[TcpPeer, AsciiInclinometer]:
    server = TcpPeer(script)
    link = LineLink("127.0.0.1", server.port, timeout_s=0.3, instrument="inclinometer 1",
                    send_end=b"\r\n")
    return server, AsciiInclinometer({1: link}, axis="x", readings=readings, u_deg=0.004)


def test_read_angle_sends_r_and_averages_the_x_axis() -> None:
    server, inc = _make(
        [Pair(R, b"X=+90.012\r\nY=-00.084\r\n"), Pair(R, b"X=+90.016\r\nY=-00.080\r\n")],
        readings=2,
    )
    try:
        angle, u = inc.read_angle(1)
        assert angle == pytest.approx(90.014)
        assert u == 0.004
        assert server.received == [R, R] and not server.errors
    finally:
        inc.close()
        server.close()


def test_identify_reads_type_and_serial() -> None:
    server, inc = _make([Pair(b"V\r\n", b"AGS360-2-S1\r\nSN:1234-567\r\n")])
    try:
        ident = inc.identify()
        assert (ident.model, ident.serial) == ("AGS360-2-S1", "1234-567")
    finally:
        inc.close()
        server.close()


@pytest.mark.parametrize(
    "reply", [b"E\r\n\r\n", b"X=90.0\r\nY=+00.000\r\n", b"X=+90.000\r\nX=+90.000\r\n"]
)
def test_a_reply_of_another_form_is_a_protocol_error(reply: bytes) -> None:
    server, inc = _make([Pair(R, reply)])
    try:
        with pytest.raises(ProtocolError, match="inclinometer 1"):
            inc.read_angle(1)
    finally:
        inc.close()
        server.close()


def test_half_a_reply_is_a_timeout_and_an_unknown_socket_says_how_to_add_it() -> None:
    server, inc = _make([Pair(R, b"X=+90.000\r\n")])
    try:
        with pytest.raises(InstrumentTimeout, match="part of its reply"):
            inc.read_angle(1)
        with pytest.raises(ProtocolError, match="instruments.inclinometer.ports"):
            inc.read_angle(2)
    finally:
        inc.close()
        server.close()


def test_settings_are_checked_and_a_dead_address_is_connection_lost() -> None:
    with pytest.raises(ValidationError):
        Settings.model_validate({"ports": {1: "nohost"}})
    with pytest.raises(ValidationError):
        Settings.model_validate({"address": "127.0.0.1:1", "readings": 0})
    with pytest.raises(ConnectionLost, match="inclinometer 1"):
        factory({"address": "127.0.0.1:1", "timeout_s": 0.2})
    name, found = registry.resolve("inclinometer", "ascii-xy")
    assert name == "inclinometer.ascii-xy" and found is factory


def test_driver_against_the_twin_reads_the_hand_turned_fixture() -> None:
    """The travel between two stops read by the inclinometer is the fixture's stop angle
    (its mounting offset cancels), to the sensor's resolution."""
    config = {
        "instruments": {"rate_table": "none", "inclinometer": "ascii-xy"},
        "parts": [{"socket": 1, "serial": "SIM-I001"}],
        "hand": {"bounce_probability": 0.0},
    }
    with launch_bench(config=config, speed=100) as bench:
        ports = bench.endpoints.raw["inclinometers"]
        inc = factory({"ports": {int(k): v for k, v in ports.items()}, "readings": 4})
        try:
            before, _ = inc.read_angle(1)
            relay = PromptRelay(bench.endpoints.raw["operator"])
            relay(ProgressEvent(kind="prompt", message="Turn socket 1's fixture", sockets={1: ""}))

            def at_stop() -> bool:
                hand = bench.control.truth()["sockets"]["1"]["hand"]
                return bool(hand["moves"]) and bench.control.world_time_s() > (
                    hand["moves"][-1]["end_s"] + 0.5
                )

            wait_until(at_stop, 10.0, "the fixture to rest at its other stop")
            after, _ = inc.read_angle(1)
            truth = bench.control.truth()["sockets"]["1"]
            assert after - before == pytest.approx(truth["stop_angle_deg"], abs=0.006)
            assert inc.identify().serial == "SIM-IN001"
            relay.close()
        finally:
            inc.close()
