"""A results.sqlite of schema 1 (made by the hand-written sqlite3 index before SQLAlchemy)
is migrated on open with nothing lost; the public methods read it as before."""

from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path

import pytest

from station.db.connect import HEAD_REVISION, dispose_all
from station.results_db import ResultsDB, ResultsDBError

SCHEMA1 = Path(__file__).parent / "data" / "results-schema1.sqlite"


@pytest.fixture
def old_file(tmp_path: Path) -> Path:
    path = tmp_path / "results.sqlite"
    shutil.copy(SCHEMA1, path)
    yield path
    dispose_all()


def _raw(path: Path, sql: str) -> list[tuple[object, ...]]:
    con = sqlite3.connect(path)
    try:
        return con.execute(sql).fetchall()
    finally:
        con.close()


def test_schema1_file_is_what_todays_code_made() -> None:
    assert _raw(SCHEMA1, "PRAGMA user_version") == [(1,)]
    names = {r[0] for r in _raw(SCHEMA1, "SELECT name FROM sqlite_master WHERE type='table'")}
    assert names == {"runs", "measurements"}


def test_migration_keeps_every_row_and_value(old_file: Path) -> None:
    runs_before = _raw(old_file, "SELECT * FROM runs ORDER BY run_id")
    meas_before = _raw(old_file, "SELECT * FROM measurements ORDER BY run_id, seq")
    assert len(runs_before) == 12 and len(meas_before) == 72

    db = ResultsDB(old_file)

    assert _raw(old_file, "SELECT version_num FROM alembic_version") == [(HEAD_REVISION,)]
    n_old = len(runs_before[0])
    runs_after = [r[:n_old] for r in _raw(old_file, "SELECT * FROM runs ORDER BY run_id")]
    assert runs_after == runs_before  # the schema-1 columns, value for value
    assert _raw(old_file, "SELECT * FROM measurements ORDER BY run_id, seq") == meas_before
    # the public methods read them back
    rows = db.runs()
    assert sorted(r.run_id for r in rows) == [r[0] for r in runs_before]
    assert len(db.measurement_values()) == 72
    assert db.runs(verdict="ERROR")[0].reason == "station stopped during the run"


def test_migration_links_retests_and_queues_every_run(old_file: Path) -> None:
    db = ResultsDB(old_file)
    by_serial: dict[str, list[tuple[str, int, str]]] = {}
    for r in db.runs():  # oldest first
        by_serial.setdefault(r.serial, []).append((r.run_id, r.attempt, r.first_run_id))
    retested = {s for s, tests in by_serial.items() if len(tests) > 1}
    assert retested == {"V1-000", "V1-001", "V1-002"}
    for tests in by_serial.values():
        assert [a for _, a, _ in tests] == list(range(1, len(tests) + 1))
        assert {f for _, _, f in tests} == {tests[0][0]}
    assert _raw(old_file, "SELECT count(*) FROM outbox WHERE sent_version < version") == [(12,)]


def test_reopening_a_migrated_file_changes_nothing(old_file: Path) -> None:
    ResultsDB(old_file)
    dump = _raw(old_file, "SELECT * FROM runs ORDER BY run_id")
    dispose_all()  # as another process would: the migration check runs again
    ResultsDB(old_file)
    assert _raw(old_file, "SELECT * FROM runs ORDER BY run_id") == dump


def test_mes_views_have_teststand_shape(old_file: Path) -> None:
    ResultsDB(old_file)
    uut = _raw(old_file, "SELECT ID, UUT_SERIAL_NUMBER, UUT_STATUS, ATTEMPT FROM UUT_RESULT "
                         "WHERE UUT_SERIAL_NUMBER = 'V1-002' ORDER BY START_DATE_TIME")
    assert [(u[2], u[3]) for u in uut] == [("Passed", 1), ("Error", 2)]
    steps = _raw(old_file, f"SELECT s.STEP_NAME, s.STATUS, l.DATA, l.LOW_LIMIT, l.HIGH_LIMIT, "
                           f"l.COMP_OPERATOR FROM STEP_RESULT s JOIN MEAS_NUMERICLIMIT l "
                           f"ON l.STEP_RESULT = s.ID WHERE s.UUT_RESULT = '{uut[0][0]}' "
                           f"ORDER BY s.ORDER_NUMBER")
    meas = _raw(old_file, f"SELECT name, value, low, high FROM measurements "
                          f"WHERE run_id = '{uut[0][0]}' ORDER BY seq")
    assert [(s[0].split(" @ ")[0], s[2], s[3], s[4]) for s in steps] == meas
    assert {s[5] for s in steps if s[3] is not None and s[4] is not None} == {"GELE"}


def test_a_file_that_is_not_a_database_says_so(tmp_path: Path) -> None:
    bad = tmp_path / "results.sqlite"
    bad.write_bytes(b"this is not sqlite" * 100)
    with pytest.raises(ResultsDBError, match="cannot open the results database"):
        ResultsDB(bad)
    dispose_all()
