"""The fixture link's baud: passed from station.yaml to every part link, and a procedure whose
output rate the link cannot carry is refused before any folder or instrument is touched."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

import station.uut as uut
from common.clock import ScaledClock
from drivers.fixture_protocol import OUTPUT_RATES_HZ
from drivers.protocols import InstrumentIdentity
from station.errors import UserError
from station.link_speed import link_speed_problem
from station.open_bench import open_bench, open_part_link
from station.settings import LoadedSettings
from station.station_file import load_settings
from station.uut import UutRunner

ROOT = Path(__file__).resolve().parents[2]
SHORT = ROOT / "tests/procedures/data/short.yaml"
PRODUCT = ROOT / "config/products/gyr130.yaml"


def _procedure(tmp_path: Path, rate_hz: int) -> Path:
    text = SHORT.read_text()
    assert text.count("output_rate_hz: 100") == 1
    path = tmp_path / f"short-{rate_hz}hz.yaml"
    path.write_text(text.replace("output_rate_hz: 100", f"output_rate_hz: {rate_hz}"))
    return path


def _settings(tmp_path: Path, baud: int | None) -> LoadedSettings:
    fixture = "    ports: {1: /dev/fixture1, 2: /dev/fixture2}\n"
    if baud is not None:
        fixture += f"    baud: {baud}\n"
    path = tmp_path / "station.yaml"
    path.write_text(
        "station: {id: LINK-TEST}\n"
        "instruments:\n"
        "  chamber: {address: 127.0.0.1:1}\n"
        "  supply: {address: /dev/supply, baud: 9600}\n"
        "  fixture:\n" + fixture
    )
    return load_settings(path)


def test_link_speed_rule_at_the_default_baud() -> None:
    ok = [r for r in OUTPUT_RATES_HZ if link_speed_problem(r, 115_200) is None]
    assert ok == [50, 100, 200]  # 500 Hz needs 125,000 baud
    assert link_speed_problem(500, 230_400) is None
    assert link_speed_problem(1000, 230_400) is not None  # 250,000 baud
    assert link_speed_problem(1000, 460_800) is None
    # the margin for replies: exactly the stream's baud is not enough
    assert link_speed_problem(200, 50_000) is not None
    assert link_speed_problem(200, 55_556) is None


def test_procedure_at_1000_hz_is_refused_at_the_default_baud(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def no_bench(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("the bench was opened")

    monkeypatch.setattr(uut, "open_bench", no_bench)
    monkeypatch.setattr(uut, "open_part_link", no_bench)
    out = tmp_path / "runs"
    runner = UutRunner(
        load_settings(),  # config/station.yaml: the fixture at its default 115,200 baud
        procedure_path=_procedure(tmp_path, 1000),
        product_path=PRODUCT,
        out=out,
        certificate=False,
    )
    for attempt in (runner.validate, runner.start, runner.run):
        with pytest.raises(UserError) as info:
            attempt({1: "SIM-0001"})
        message = str(info.value)
        assert "1000 Hz needs 250,000 baud" in message, message
        assert "115,200 baud" in message
        assert "raise instruments.fixture.baud in station.yaml to 460,800" in message
        assert "lower power.output_rate_hz in the procedure to 200 Hz or less" in message
    assert not out.exists()  # no run folder, no results database
    assert runner.state()["state"] == "idle"


def test_fast_procedure_runs_when_the_fixture_baud_is_raised(tmp_path: Path) -> None:
    procedure = _procedure(tmp_path, 1000)
    fast = UutRunner(
        _settings(tmp_path, 460_800), procedure_path=procedure, product_path=PRODUCT,
        out=tmp_path / "runs",
    )
    assert fast.validate({1: " SIM-0001 "}) == {1: "SIM-0001"}
    slow = UutRunner(
        _settings(tmp_path, 230_400), procedure_path=procedure, product_path=PRODUCT,
        out=tmp_path / "runs",
    )
    with pytest.raises(UserError, match=r"1000 Hz needs 250,000 baud.* 230,400 baud"):
        slow.validate({1: "SIM-0001"})


class _Instrument:
    def identify(self) -> InstrumentIdentity:
        return InstrumentIdentity("TestCo", "X", "1", "1.0")

    def part_present(self) -> bool:
        return False

    def stop_stream(self) -> None:  # every socket's stream is stopped at the start
        pass

    def close(self) -> None:
        pass


def test_configured_fixture_baud_reaches_every_part_link(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    opened: list[tuple[str, int]] = []

    def fake_open(path: str, clock: ScaledClock, *, baudrate: int, **kwargs: Any) -> _Instrument:
        opened.append((path, baudrate))
        return _Instrument()

    # the part.fixture driver's factory opens its port through SerialPartLink.open
    monkeypatch.setattr("drivers.part_link.SerialPartLink.open", fake_open)
    monkeypatch.setattr("drivers.chamber.ModbusChamber.connect", lambda *a, **k: _Instrument())
    monkeypatch.setattr("drivers.supply.ScpiSupply.open", lambda *a, **k: _Instrument())
    settings = _settings(tmp_path, 230_400)
    bench = open_bench(settings, [1], None, needs_table=False)
    bench.close()
    assert opened == [("/dev/fixture1", 230_400)]
    # the presence check of the sockets that were not scanned opens them at that rate too
    runner = UutRunner(settings, procedure_path=SHORT, out=tmp_path / "runs")
    opened.clear()
    assert runner._unscanned_parts(ScaledClock(1.0), {1}) == ([], [])
    assert opened == [("/dev/fixture2", 230_400)]


def test_real_link_opens_at_the_configured_baud(tmp_path: Path) -> None:
    import os
    import tty

    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        path = tmp_path / "station.yaml"
        path.write_text(
            "station: {id: LINK-TEST}\ninstruments:\n"
            f"  fixture: {{ports: {{1: {os.ttyname(slave)}}}, baud: 460800}}\n"
        )
        link = open_part_link(load_settings(path), 1, os.ttyname(slave), ScaledClock(1.0), 5.0)
        try:
            assert link._port.baudrate == 460_800  # type: ignore[attr-defined]
        finally:
            link.close()
    finally:
        os.close(master)
        os.close(slave)


def test_three_axis_procedure_is_refused_where_its_longer_frames_do_not_fit(
    tmp_path: Path,
) -> None:
    """At 200 Hz a single-axis part's 25-byte frames need 50,000 baud, a three-axis part's
    40-byte frames 80,000: a 57,600-baud fixture carries the first and not the second."""
    settings = _settings(tmp_path, 57_600)
    single = UutRunner(settings, procedure_path=_procedure(tmp_path, 200), product_path=PRODUCT,
                       out=tmp_path / "runs")
    assert single.validate({1: "SIM-0001"}) == {1: "SIM-0001"}
    text = (ROOT / "tests/data/eol-three-axis-short.yaml").read_text()
    three = tmp_path / "three-200hz.yaml"
    three.write_text(
        text.replace("output_rate_hz: 100", "output_rate_hz: 200").replace(
            "../../config/products/imu3.yaml", str(ROOT / "config/products/imu3.yaml"))
    )
    runner = UutRunner(settings, procedure_path=three, out=tmp_path / "runs")
    with pytest.raises(UserError) as info:
        runner.validate({1: "IMU-0001"})
    assert "200 Hz needs 80,000 baud for its 40-byte sample frames" in str(info.value)
    assert "57,600 baud" in str(info.value)
    assert not (tmp_path / "runs").exists()
