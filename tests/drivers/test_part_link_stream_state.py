"""The stream's safe state read back from the fixture (`STREAM?`), never assumed: the part
link against a scripted fixture over a pty, and the simulated fixture's own answers."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from common.clock import ScaledClock
from drivers import fixture_protocol as fp
from drivers.part_link import SerialPartLink
from drivers.sim.config import parse_sim_config
from drivers.sim.world import World
from tests.drivers._fixture_fake import FakeFixture


@pytest.fixture
def rig() -> Iterator[tuple[FakeFixture, SerialPartLink]]:
    fixture = FakeFixture(rate_fps=200.0)
    link = SerialPartLink.open(fixture.path, ScaledClock(1.0), reply_timeout_s=0.5)
    yield fixture, link
    link.close()
    fixture.close()


def test_a_stream_another_process_started_is_stopped_and_read_back(rig) -> None:
    fixture, link = rig
    fixture.knows_stream_query = True
    link.command("START")  # as a crashed station did: this link's own flag knows nothing
    assert link.check_stream_stopped().safe is False
    link.stop_stream()
    back = link.check_stream_stopped()
    assert back.safe and back.detail == "stream stopped (STREAM? 0)"
    assert fixture.commands[-2:] == [b"STOP", b"STREAM?"]


def test_a_fixture_whose_stop_does_not_stop_is_not_called_safe(rig) -> None:
    fixture, link = rig
    fixture.knows_stream_query = fixture.stop_ignored = True
    link.start_stream()
    link.stop_stream()
    back = link.check_stream_stopped()
    assert not back.safe and "STREAM? 1" in back.detail


def test_older_firmware_is_sent_stop_and_its_ok_taken(rig) -> None:
    fixture, link = rig
    back = link.check_stream_stopped()  # ERR 2 unknown command
    assert back.safe and "cannot report" in back.detail
    assert fixture.commands == [b"STREAM?", b"STOP"]


def test_the_simulated_fixture_keeps_its_stream_across_a_power_cycle() -> None:
    world = World(parse_sim_config({"parts": [{"socket": 1, "serial": "SIM-0001"}]}),
                  lockstep=True)
    sock = world.sockets[1]
    world.supply.handle("VOLT 5.0")
    world.supply.handle("OUTP ON")
    world.advance_to(1.0)

    def ask(line: str) -> str:
        frames = sock.handle_line(line, world.now_s())
        return fp.FrameParser().feed(frames).replies[-1]

    assert ask("STREAM?") == "OK 0"
    assert ask("START") == "OK"
    world.supply.handle("OUTP OFF")  # the part loses power: the stream stays started
    world.advance_to(2.0)
    assert not sock.part_powered()
    assert ask("STREAM?") == "OK 1"
    assert ask("ODR 50").startswith("ERR 5")  # what the crashed station's successor met
    assert ask("STOP") == "OK" and ask("STREAM?") == "OK 0"
    assert ask("ODR 50") == "OK"
