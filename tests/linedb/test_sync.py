"""Store-and-forward to a central database (SQLite here; PostgreSQL in test_postgres_line):
exactly once by run_id, re-sent when re-indexed, queued through an outage."""

from __future__ import annotations

import sqlite3
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from station.db.connect import dispose_all
from station.db.sync import Sync, SyncError, SyncThread, wait_delivered
from station.results_db import ResultsDB
from tests.linedb.linekit import line_runs


@pytest.fixture(autouse=True)
def _fresh_engines() -> Iterator[None]:
    yield
    dispose_all()


def _count(path: Path, sql: str) -> int:
    con = sqlite3.connect(path)
    try:
        return int(con.execute(sql).fetchone()[0])
    finally:
        con.close()


def test_each_run_arrives_once_and_again_when_reindexed(tmp_path: Path) -> None:
    local = ResultsDB(tmp_path / "local.sqlite")
    runs = line_runs(30, ["EOL-A"], root=tmp_path)
    local.add_records([(r.folder, r.record) for r in runs])
    sync = Sync(str(local.path), str(tmp_path / "central.sqlite"), station_id="EOL-A")

    first = sync.push_once()
    again = sync.push_once()

    assert (first.sent, first.pending, again.sent) == (len(runs), 0, 0)
    central = ResultsDB(tmp_path / "central.sqlite")
    assert sorted(r.run_id for r in central.runs()) == sorted(r.record.run_id for r in runs)
    n_meas = sum(len(r.record.measurements) for r in runs)
    assert _count(tmp_path / "central.sqlite", "SELECT count(*) FROM measurements") == n_meas

    victim = runs[3].record.run_id
    local.mark_error(victim, "found crashed")
    assert sync.push_once().sent == 1
    (row,) = [r for r in central.runs() if r.run_id == victim]
    assert (row.verdict, row.reason) == ("ERROR", "found crashed")
    assert len(central.runs()) == len(runs)


def test_outage_queues_runs_and_the_station_keeps_writing(tmp_path: Path) -> None:
    local = ResultsDB(tmp_path / "local.sqlite")
    blocked = tmp_path / "central-dir"
    blocked.write_text("a file where the central database's folder should be")
    sync = Sync(str(local.path), str(blocked / "central.sqlite"), station_id="EOL-A")
    runs = line_runs(10, ["EOL-A"], root=tmp_path)
    for r in runs[:5]:
        local.add_run(r.folder, r.record)
        with pytest.raises(SyncError, match="stay queued locally"):
            sync.push_once()
    assert sync.pending() == 5

    blocked.unlink()  # the central database comes back
    for r in runs[5:]:
        local.add_run(r.folder, r.record)
    assert sync.push_once().sent == len(runs)
    central = ResultsDB(blocked / "central.sqlite")
    assert len({r.run_id for r in central.runs()}) == len(central.runs()) == len(runs)


def test_sync_thread_backs_off_during_an_outage_then_delivers(tmp_path: Path) -> None:
    local = ResultsDB(tmp_path / "local.sqlite")
    blocked = tmp_path / "central-dir"
    blocked.write_text("not a folder")
    sync = Sync(str(local.path), str(blocked / "central.sqlite"))
    thread = SyncThread(sync, interval_s=0.05, max_backoff_s=0.4)
    delays = []
    for failures in range(6):
        thread.failures = failures
        delays.append(thread.delay_s())
    assert delays == [0.05, 0.1, 0.2, 0.4, 0.4, 0.4]
    thread.failures = 0
    runs = line_runs(6, ["EOL-A"], root=tmp_path)
    local.add_records([(r.folder, r.record) for r in runs])
    thread.start()
    try:
        assert not wait_delivered(sync, timeout_s=0.3)
        assert thread.failures >= 1 and "not reachable" in thread.last_error
        before = thread.failures
        for _ in range(30):  # runs ending during the outage: the backoff holds
            thread.wake()
            time.sleep(0.01)
        assert thread.failures - before <= 3
        blocked.unlink()
        thread.wake(force=True)
        assert wait_delivered(sync, timeout_s=10.0)
    finally:
        thread.stop()
    assert len(ResultsDB(blocked / "central.sqlite").runs()) == len(runs)


def test_central_db_that_is_the_local_one_is_refused(tmp_path: Path) -> None:
    with pytest.raises(SyncError, match="own results_db"):
        Sync(str(tmp_path / "same.sqlite"), f"sqlite:///{tmp_path / 'same.sqlite'}")
