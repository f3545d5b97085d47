"""station.yaml names several fixture boards: their ports join the fixture's, 32 sockets."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from station.settings import FixtureSettings
from station.station_file import load_settings

ROOT = Path(__file__).resolve().parents[2]


def _board(name: str, first: int, n: int = 8) -> dict[str, object]:
    return {"name": name, "ports": {s: f"/dev/tty{name}-{s}" for s in range(first, first + n)}}


def test_boards_ports_join_the_fixture_ports_and_set_the_socket_count() -> None:
    fx = FixtureSettings.model_validate(
        {"boards": [_board("A", 1), _board("B", 9)], "baud": 230400}
    )
    assert fx.sockets == 16
    assert fx.ports[9] == "/dev/ttyB-9" and sorted(fx.ports) == list(range(1, 17))
    assert fx.board_of(3) == "A" and fx.board_of(16) == "B" and fx.board_of(17) is None
    # the part driver gets its socket's port, never the board list
    assert fx.driver_settings(12, fx.ports[12]) == {
        "baud": 230400, "address": "/dev/ttyB-12", "socket": 12
    }


def test_a_socket_on_two_boards_is_refused_with_the_board_named() -> None:
    with pytest.raises(ValidationError, match="socket 8 is given two ports.*board B"):
        FixtureSettings.model_validate({"boards": [_board("A", 1), _board("B", 8)]})


def test_more_than_64_sockets_are_refused() -> None:
    with pytest.raises(ValidationError, match="1..64"):
        FixtureSettings.model_validate({"boards": [_board("A", 60)]})


def test_the_32_socket_station_file_is_four_boards_of_eight() -> None:
    settings = load_settings(ROOT / "config" / "station-32.yaml")
    fx = settings.settings.instruments.fixture
    assert fx.sockets == 32 and sorted(fx.ports) == list(range(1, 33))
    assert [b.name for b in fx.boards] == ["FX-B1", "FX-B2", "FX-B3", "FX-B4"]
    assert [sorted(b.ports) for b in fx.boards] == [
        list(range(8 * b + 1, 8 * b + 9)) for b in range(4)
    ]
    assert settings.settings.sim_config is not None
    assert settings.resolve(settings.settings.sim_config).is_file()
