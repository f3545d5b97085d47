"""The results database: upsert, filters, error marking, measurement queries."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from procedures.runtime.record import Outcome, Verdict
from station.results_db import ResultsDB, ResultsDBError
from tests.reports.lot_data import make_lot
from tests.reports.synth_run import Part, make_record


def test_schema_is_created_and_a_run_round_trips(tmp_path: Path) -> None:
    db = ResultsDB(tmp_path / "sub" / "results.sqlite")
    rec = make_record(Part(serial="SIM-1", bias_dps=12.0))
    db.add_run(tmp_path / rec.run_id, rec)
    (row,) = db.runs()
    assert (row.run_id, row.serial, row.verdict) == (rec.run_id, "SIM-1", "FAIL")
    assert row.failed_measurements == ("bias_dps",)
    assert row.calibration["bias_dps"] == 12.0 and row.calibration["scale"] == 1.0567
    assert row.started_utc == "2026-11-21T09:30:00+00:00"
    values = db.measurement_values()
    assert [m.name for m in values] == [m.name for m in rec.measurements]
    assert [m.value for m in values] == [m.value for m in rec.measurements]


def test_add_run_again_replaces_the_run_and_its_measurements(tmp_path: Path) -> None:
    db = ResultsDB(tmp_path / "r.sqlite")
    rec = make_record(Part(serial="SIM-2"))
    db.add_run(tmp_path / rec.run_id, rec)
    fewer = rec.measurements[:2]
    changed = rec.model_copy(update={"verdict": Verdict.FAIL, "measurements": fewer})
    db.add_run(tmp_path / rec.run_id, changed)
    assert [r.verdict for r in db.runs()] == ["FAIL"]
    assert len(db.measurement_values()) == 2
    with sqlite3.connect(db.path) as con:
        assert con.execute("SELECT count(*) FROM runs").fetchone()[0] == 1


def test_filters_since_product_verdict_serial(tmp_path: Path) -> None:
    path = tmp_path / "r.sqlite"
    recs = make_lot(path, 30) + make_lot(path, 5, product="OTHER", start_index=30)
    db = ResultsDB(path)
    assert len(db.runs()) == 35
    assert {r.product for r in db.runs(product="OTHER")} == {"OTHER"}
    cut = recs[10].started_utc
    since = db.runs(since=cut)
    assert len(since) == 25 and all(r.started_utc >= "2026-11-21T15:20:00+00:00" for r in since)
    assert len(db.runs(since="2026-11-22")) == sum(r.started_utc >= "2026-11-22" for r in recs)
    fails = db.runs(verdict="fail")
    assert len(fails) == sum(r.verdict == Verdict.FAIL for r in recs) > 0
    assert [r.serial for r in db.runs(serial="LOT-00003")] == ["LOT-00003"]
    assert db.runs(product="OTHER", verdict="PASS", since="2030-01-01") == []


def test_measurement_values_of_one_name_follow_the_filters(tmp_path: Path) -> None:
    path = tmp_path / "r.sqlite"
    recs = make_lot(path, 20)
    db = ResultsDB(path)
    got = [m.value for m in db.measurement_values("scale")]
    assert got == [next(m.value for m in r.measurements if m.name == "scale") for r in recs]
    failing = db.measurement_values("bias_dps", verdict="FAIL")
    assert all(m.verdict == "FAIL" for m in failing)
    assert db.measurement_names()[0] == "bias_dps"


def test_mark_error_sets_verdict_and_reason(tmp_path: Path) -> None:
    db = ResultsDB(tmp_path / "r.sqlite")
    rec = make_record(Part(serial="SIM-3", verdict="RUNNING"))
    db.add_run(tmp_path / rec.run_id, rec)
    db.mark_error(rec.run_id, "station restarted while the run was in progress")
    (row,) = db.runs()
    assert row.verdict == "ERROR" and "restarted" in row.reason
    with pytest.raises(ResultsDBError, match="not in"):
        db.mark_error("no-such-run", "x")


def test_bad_since_says_which_format_to_use(tmp_path: Path) -> None:
    db = ResultsDB(tmp_path / "r.sqlite")
    with pytest.raises(ResultsDBError, match="YYYY-MM-DD"):
        db.runs(since="last tuesday")


def test_unopenable_database_says_what_to_do(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.raises(ResultsDBError, match="--db"):
        ResultsDB(blocker / "results.sqlite")


def test_outcomes_are_stored_as_judged(tmp_path: Path) -> None:
    db = ResultsDB(tmp_path / "r.sqlite")
    rec = make_record(Part(serial="SIM-4", scale=1.055))  # inside limits, in the marginal band
    db.add_run(tmp_path / rec.run_id, rec)
    (scale,) = db.measurement_values("scale")
    assert scale.outcome == Outcome.MARGINAL.value
