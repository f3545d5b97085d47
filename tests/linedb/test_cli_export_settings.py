"""`results_db:` as a URL or a path, `station export --format cfx`, `station sync`."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest

from station.cli.main import main
from station.db.connect import database_url, dispose_all
from station.results_db import ResultsDB
from station.station_file import load_settings
from tests.linedb.linekit import line_runs, station_yaml


@pytest.fixture(autouse=True)
def _fresh_engines() -> Iterator[None]:
    yield
    dispose_all()


@pytest.mark.parametrize("text,expect", [
    ("runs/results.sqlite", "{base}/runs/results.sqlite"),
    ("sqlite:///runs/r.sqlite", "{base}/runs/r.sqlite"),
    ("/abs/r.sqlite", "/abs/r.sqlite"),
    ("postgresql+psycopg://gyro@db.line/line", "postgresql+psycopg://gyro@db.line/line"),
])
def test_results_db_takes_a_url_or_a_path(tmp_path: Path, text: str, expect: str) -> None:
    settings = load_settings(station_yaml(tmp_path / "st", "EOL-X", None, text))
    got = settings.results_db
    want = expect.format(base=(tmp_path / "st").resolve())
    assert str(got) == want
    assert isinstance(got, Path) == (not want.startswith("postgresql"))
    assert settings.central_db is None


def test_central_db_relative_sqlite_is_resolved(tmp_path: Path) -> None:
    settings = load_settings(station_yaml(tmp_path / "st", "EOL-X", "line.sqlite", "r.sqlite"))
    assert settings.central_db == database_url((tmp_path / "st" / "line.sqlite").resolve())


def test_a_bad_url_says_what_to_give() -> None:
    from station.results_db import ResultsDBError

    with pytest.raises(ResultsDBError, match="sqlite:///PATH"):
        ResultsDB("postgresql+psycopg://gyro@[::1/x")


def test_export_cfx_units_tested(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    db_path = tmp_path / "r.sqlite"
    work = line_runs(12, ["EOL-A"], root=tmp_path)
    ResultsDB(db_path).add_records([(r.folder, r.record) for r in work])
    out = tmp_path / "cfx.jsonl"
    assert main(["export", "--format", "cfx", "--db", str(db_path), "--out", str(out)]) == 0
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    assert len(lines) == len(work)
    by_serial = {m["MessageBody"]["TestedUnits"][0]["UnitIdentifier"]: m for m in lines}
    rec = work[0].record
    msg = by_serial[rec.dut.serial]
    assert msg["MessageName"] == "CFX.Production.TestAndInspection.UnitsTested"
    unit = msg["MessageBody"]["TestedUnits"][0]
    assert unit["OverallResult"] == {"PASS": "Passed", "FAIL": "Failed"}[rec.verdict.value]
    tests = unit["Tests"]
    assert len(tests) == len(rec.measurements)
    for t, m in zip(tests, rec.measurements, strict=True):
        measured = t["Measurements"][0]["MeasuredValue"]
        assert (measured["Value"], measured["MinimumAcceptableValue"],
                measured["MaximumAcceptableValue"]) == (m.value, m.low, m.high)
    # exported again: the same ids (an MES can de-duplicate)
    assert main(["export", "--format", "cfx", "--db", str(db_path)]) == 0
    again = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [m["UniqueID"] for m in again] == [m["UniqueID"] for m in lines]


def test_station_sync_once(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    local = tmp_path / "local.sqlite"
    work = line_runs(8, ["EOL-A"], root=tmp_path)
    ResultsDB(local).add_records([(r.folder, r.record) for r in work])
    central = f"sqlite:///{tmp_path / 'central.sqlite'}"
    assert main(["sync", "--db", str(local), "--central", central]) == 0
    assert f"sent {len(work)} runs" in capsys.readouterr().err
    assert len(ResultsDB(central).runs()) == len(work)
    blocked = tmp_path / "file"
    blocked.write_text("x")
    ResultsDB(local).mark_error(work[0].record.run_id, "crashed")
    assert main(["sync", "--db", str(local), "--central", str(blocked / "c.sqlite")]) == 2
    assert "stay queued locally" in capsys.readouterr().err
