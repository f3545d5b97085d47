"""Two stations and a real PostgreSQL server as the line's central database.

The parts are record-level runs through the same function the station calls when a run ends
(station.db.sync.store_finished_run, called by UutRunner._store): index locally, wake the
station's sync thread. Mid-way the server is stopped; the stations keep testing; the server
starts again: every run arrives exactly once, nothing is lost, the local copies match.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import sqlalchemy as sa

from station.db import sync as sync_mod
from station.db.connect import engine_for
from station.db.schema import measurements, runs, stations
from station.results_db import ResultsDB
from station.station_file import load_settings
from tests.linedb.linekit import line_runs, station_yaml
from tests.linedb.pgserver import PgServer, started_server

STATIONS = ("EOL-A", "EOL-B")
# the line's view of a serial (its tests on every station)
LINK_COLUMNS = {"attempt", "first_run_id", "unit_verdict", "unit_tests"}


@pytest.fixture
def pg() -> Iterator[PgServer]:
    with started_server() as server:
        try:
            yield server
        finally:
            sync_mod.stop_all()


def _rows(url: str, table: sa.Table, order: list[str]) -> list[dict[str, Any]]:
    with engine_for(url).connect() as con:
        return [dict(r) for r in con.execute(
            sa.select(table).order_by(*[table.c[o] for o in order])).mappings()]


def test_two_stations_through_a_database_outage(pg: PgServer, tmp_path: Path) -> None:
    settings = {
        sid: load_settings(station_yaml(tmp_path / sid, sid, pg.url, "runs/results.sqlite",
                                        sync_interval_s=0.5))
        for sid in STATIONS
    }
    work = line_runs(60, list(STATIONS), seed=21, root=tmp_path / "runs")
    per_station = {sid: [r for r in work if r.record.station["id"] == sid] for sid in STATIONS}
    stored = {sid: 0 for sid in STATIONS}
    outage = threading.Event()
    errors: list[BaseException] = []

    def station(sid: str) -> None:
        try:
            db = ResultsDB(settings[sid].results_db)
            for i, r in enumerate(per_station[sid]):
                if i == len(per_station[sid]) // 3:
                    outage.wait(30)  # the server goes down here, while this station tests on
                sync_mod.store_finished_run(db, settings[sid], r.folder, r.record,
                                            state=lambda: "running")
                stored[sid] += 1
                time.sleep(0.01)
        except BaseException as exc:  # reported by the test below
            errors.append(exc)

    threads = [threading.Thread(target=station, args=(sid,)) for sid in STATIONS]
    for t in threads:
        t.start()
    time.sleep(0.5)
    pg.stop()  # mid-run
    outage.set()
    for t in threads:
        t.join(60)
    assert not errors, errors
    assert stored == {sid: len(per_station[sid]) for sid in STATIONS}  # kept testing
    syncs = [t for t in sync_mod._threads.values()]
    assert len(syncs) == 2
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and not all(t.failures for t in syncs):
        time.sleep(0.1)
    assert all(t.failures >= 1 for t in syncs), "the syncs never saw the outage"
    assert all(t.sync.pending() > 0 for t in syncs)  # queued locally, not lost

    pg.start()
    for t in syncs:
        t.wake(force=True)  # as `station sync` or a restart would, not waiting for the backoff
        assert sync_mod.wait_delivered(t.sync, timeout_s=60), t.last_error

    central_runs = _rows(pg.url, runs, ["run_id"])
    ids = [r["run_id"] for r in central_runs]
    assert sorted(ids) == sorted(r.record.run_id for r in work)  # all, and each once
    assert len(set(ids)) == len(ids)
    central_meas = _rows(pg.url, measurements, ["run_id", "seq"])
    assert len(central_meas) == sum(len(r.record.measurements) for r in work)

    for sid in STATIONS:  # the local copies match the central one, column for column
        local_url = ResultsDB(settings[sid].results_db).url
        local_runs = _rows(local_url, runs, ["run_id"])
        by_id = {r["run_id"]: r for r in central_runs}
        for row in local_runs:
            assert {k: v for k, v in row.items() if k not in LINK_COLUMNS} == {
                k: v for k, v in by_id[row["run_id"]].items() if k not in LINK_COLUMNS}
        local_ids = {r["run_id"] for r in local_runs}
        assert [m for m in central_meas if m["run_id"] in local_ids] == _rows(
            local_url, measurements, ["run_id", "seq"])

    # the line links a retest on one station to the serial's first test on the other
    crossed = [r for r in central_runs if r["attempt"] > 1]
    assert crossed
    for r in crossed:
        first = next(x for x in central_runs if x["run_id"] == r["first_run_id"])
        assert first["serial"] == r["serial"] and first["attempt"] == 1
    with engine_for(pg.url).connect() as con:
        beats = {b.station_id: (b.pending_runs, b.state)
                 for b in con.execute(sa.select(stations))}
        uut = con.execute(sa.text("SELECT count(*) FROM UUT_RESULT")).scalar()
    assert beats == {sid: (0, "running") for sid in STATIONS}  # each station's last word
    assert uut == len(work)
