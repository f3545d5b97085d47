"""Fixtures for the UI tests: the web app around a fake runner, served on a free port."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from station.ui.app import create_app
from station.ui.controller import Controller
from station.ui.history import History
from station.ui.hub import Hub
from station.ui.server import BackgroundServer, serve_in_thread
from tests.ui.stationkit import (  # noqa: F401 - re-exported for the tests
    _HASH,
    ENGINEER_PASSWORD,
    FAIL_SERIAL,
    PASS_SERIAL,
    SimStation,
    make_station_config,
    start_ui_process,
    stop_ui_process,
)


@dataclass
class FakeStation:
    runner: object
    controller: Controller
    server: BackgroundServer
    out_dir: Path

    @property
    def url(self) -> str:
        return self.server.url


@pytest.fixture
def fake_station(tmp_path: Path) -> Iterator[FakeStation]:
    from tests.ui.fake_runner import FakeRunner

    runner = FakeRunner(tmp_path / "runs", step_s=0.08)
    controller = Controller(runner, Hub())
    app = create_app(controller, History(tmp_path / "runs"), engineer_password_hash=_HASH)
    server = serve_in_thread(app, before_stop=controller.hub.close)
    try:
        yield FakeStation(runner, controller, server, tmp_path / "runs")
    finally:
        runner.close()
        server.stop()


# `browser` and `page` come from tests/conftest.py (shared with tests/linedb).


# ---------------------------------------------------------------- the real station, simulated bench


@pytest.fixture(scope="module")
def sim_station(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SimStation]:
    folder = tmp_path_factory.mktemp("station") / "config"
    make_station_config(folder)
    station = start_ui_process(folder, folder.parent / "ui.log")
    try:
        yield station
    finally:
        stop_ui_process(station.process)
