"""The sync in batches, into a real PostgreSQL server and into SQLite: a few thousand runs
(some three-axis, with calibration elements) delivered batch by batch; a batch interrupted
inside its central transaction, a batch delivered but not marked sent (the station died
between the two), and a full re-send all leave exactly one copy of each run with its own
measurements and elements, counted by plain SQL on a connection of its own; so do two
syncs of one station pushing at once."""

from __future__ import annotations

import sqlite3
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from procedures.runtime.record import RunRecord
from station.db import store
from station.db.connect import dispose_all, engine_for
from station.db.links import LINK_COLUMNS
from station.db.sync import Sync, SyncError
from station.results_db import ResultsDB
from tests.linedb.linekit import LineRun, as_three_axis, line_runs
from tests.linedb.pgserver import started_server

UNITS = 2500  # about 2,800 runs (retests), 6 measurements each
BATCH = 500
Counts = dict[str, tuple[int, ...]]


def _three_axis(record: RunRecord, shift: float) -> RunRecord:
    """The record as a three-axis part: 33 calibration elements."""
    return as_three_axis(record, shift, store.ELEMENT_QUANTITIES)


@pytest.fixture(scope="module")
def work() -> list[LineRun]:
    plain = line_runs(UNITS, ["EOL-A"], seed=13, root=Path("/runs"))
    return [LineRun(r.folder, _three_axis(r.record, i) if i % 10 == 0 else r.record)
            for i, r in enumerate(plain)]


@pytest.fixture(autouse=True)
def _fresh_engines() -> Iterator[None]:
    yield
    dispose_all()


def _pg_counter(url: str) -> Callable[[str], list[tuple[Any, ...]]]:
    import psycopg

    def query(sql: str) -> list[tuple[Any, ...]]:
        with psycopg.connect(url.replace("postgresql+psycopg://", "postgresql://")) as con:
            return list(con.execute(sql).fetchall())

    return query


def _sqlite_counter(path: Path) -> Callable[[str], list[tuple[Any, ...]]]:
    def query(sql: str) -> list[tuple[Any, ...]]:
        con = sqlite3.connect(path)
        try:
            return list(con.execute(sql).fetchall())
        finally:
            con.close()

    return query


@pytest.fixture(params=["postgresql", "sqlite"])
def central(request: pytest.FixtureRequest, tmp_path: Path
            ) -> Iterator[tuple[str, Callable[[str], list[tuple[Any, ...]]]]]:
    """The central database's URL and a plain-SQL query on a connection of its own."""
    if request.param == "sqlite":
        path = tmp_path / "central.sqlite"
        yield f"sqlite:///{path}", _sqlite_counter(path)
        return
    with started_server() as server:
        yield server.url, _pg_counter(server.url)


def _expected(runs: list[LineRun]) -> Counts:
    """run_id -> (measurements, calibration elements), straight from the records."""
    return {r.record.run_id: (len(r.record.measurements), len(store.element_rows(r.record)))
            for r in runs}


def _found(query: Callable[[str], list[tuple[Any, ...]]]) -> Counts:
    """run_id -> (copies, measurements, elements) in the central database, by plain SQL."""
    copies = dict(query("SELECT run_id, count(*) FROM runs GROUP BY run_id"))
    meas = dict(query("SELECT run_id, count(*) FROM measurements GROUP BY run_id"))
    elements = dict(query("SELECT run_id, count(*) FROM calibration_elements GROUP BY run_id"))
    return {rid: (n, meas.get(rid, 0), elements.get(rid, 0)) for rid, n in copies.items()}


def _once_each(runs: list[LineRun]) -> Counts:
    return {rid: (1, m, e) for rid, (m, e) in _expected(runs).items()}


def _interrupt(monkeypatch: pytest.MonkeyPatch, target: Any, name: str, on_call: int) -> None:
    """target.name raises on its on_call-th call (1-based); the calls before pass through."""
    real = getattr(target, name)
    calls = [0]

    def flaky(*args: Any, **kwargs: Any) -> Any:
        calls[0] += 1
        if calls[0] == on_call:
            raise RuntimeError(f"injected: {name} call {on_call}")
        return real(*args, **kwargs)

    monkeypatch.setattr(target, name, flaky)


def test_batches_interrupted_and_resent_leave_one_copy_of_each_run(
        work: list[LineRun], central: tuple[str, Any], tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    url, query = central
    local = ResultsDB(tmp_path / "local.sqlite")
    local.add_records([(r.folder, r.record) for r in work])
    sync = Sync(str(local.path), url, station_id="EOL-A", batch=BATCH)
    assert len(work) > 5 * BATCH and sum(e for _, e in _expected(work).values()) > 0
    order = sorted(work, key=lambda r: r.record.run_id)  # the outbox's order (queued together)

    # the third batch fails inside its central transaction: nothing of it arrives
    with monkeypatch.context() as m:
        _interrupt(m, store, "relink_units", on_call=3)
        with pytest.raises(RuntimeError, match="injected"):
            sync.push_once()
    assert _found(query) == _once_each(order[: 2 * BATCH])
    assert sync.pending() == len(work) - 2 * BATCH

    # the next batch commits centrally, then the station dies before marking it sent
    with monkeypatch.context() as m:
        _interrupt(m, Sync, "_mark_sent", on_call=1)
        with pytest.raises(RuntimeError, match="injected"):
            sync.push_once()
    assert _found(query) == _once_each(order[: 3 * BATCH])
    assert sync.pending() == len(work) - 2 * BATCH  # that batch is still queued

    report = sync.push_once()  # the retry: the unmarked batch again, then the rest
    assert (report.sent, report.pending) == (len(work) - 2 * BATCH, 0)
    assert _found(query) == _once_each(work)

    with engine_for(local.url).begin() as con:  # everything sent again from scratch
        con.exec_driver_sql("UPDATE outbox SET sent_version = 0")
    assert sync.push_once().sent == len(work)
    assert _found(query) == _once_each(work)
    assert query("SELECT count(*), count(DISTINCT run_id) FROM runs") == [(len(work),) * 2]
    links = f"SELECT run_id, {', '.join(LINK_COLUMNS)} FROM runs ORDER BY run_id"
    retested = query("SELECT count(*) FROM runs WHERE attempt > 1")[0][0]
    assert retested > 0  # a retest in a later batch relinked its unit's earlier runs
    assert query(links) == _sqlite_counter(tmp_path / "local.sqlite")(links)


def test_two_syncs_of_one_station_at_once_leave_one_copy_of_each_run(
        work: list[LineRun], central: tuple[str, Any], tmp_path: Path) -> None:
    """`station sync` by hand while the station's own sync thread pushes the same outbox:
    both deliver the same batches at once (SQLite may refuse the second writer: the runs
    stay queued and go with the next push)."""
    url, query = central
    some = work[: 3 * BATCH]
    local = ResultsDB(tmp_path / "local.sqlite")
    local.add_records([(r.folder, r.record) for r in some])
    syncs = [Sync(str(local.path), url, batch=BATCH) for _ in range(2)]
    start = threading.Barrier(len(syncs))
    failed: list[BaseException] = []

    def push(sync: Sync) -> None:
        start.wait()
        try:
            sync.push_once()
        except SyncError as exc:
            failed.append(exc)

    threads = [threading.Thread(target=push, args=(s,)) for s in syncs]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert len(failed) < len(syncs), failed
    if url.startswith("postgresql"):  # the second waits for the first's units, then replaces
        assert not failed, failed
    syncs[0].push_once()
    assert syncs[0].pending() == 0
    assert _found(query) == _once_each(some)
