"""Rollups kept up to date by the sync equal a direct computation from the runs: after each
batch, after the same runs are delivered again (no double count), on PostgreSQL and SQLite;
and the migration fills them in for a database that had runs before."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import asdict
from datetime import timedelta
from itertools import zip_longest
from pathlib import Path

import pytest
import sqlalchemy as sa

from station.db.connect import dispose_all, engine_for
from station.db.rollups import add_hourly, grain
from station.db.schema import (
    MEASUREMENT_ROLLUPS,
    RUN_ROLLUPS,
    outbox,
    rollup_measurements,
    rollup_runs,
)
from station.db.sync import Sync
from station.db.yields import DEFAULT_SHIFT_STARTS_H, GROUPS, yields_by
from station.line import queries, rolled
from station.line.queries import Filters
from station.results_db import ResultsDB
from tests.linedb.linekit import START, line_record, line_runs
from tests.linedb.pgserver import started_server
from tests.linedb.rollkit import direct_rollups, kept_rollups

BATCH = 100


@pytest.fixture(autouse=True)
def _fresh_engines() -> Iterator[None]:
    yield
    dispose_all()


@pytest.fixture(params=["postgresql", "sqlite"])
def central(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'central.sqlite'}"
        return
    with started_server() as server:
        yield server.url


def _compare(url: str) -> int:
    """Every grain's rollups equal the direct computation; the runs counted."""
    grains = zip_longest(RUN_ROLLUPS, MEASUREMENT_ROLLUPS, fillvalue=rollup_measurements)
    with engine_for(url).connect() as con:
        for run_table, measurement_table in grains:
            direct = direct_rollups(con, grain(run_table), grain(measurement_table))
            kept = kept_rollups(con, run_table, measurement_table)
            assert kept[0] == direct[0], run_table.name
            assert kept[1] == direct[1], measurement_table.name
            assert kept[0], run_table.name
        counts = direct_rollups(con)[0]
    return sum(c[0] for c in counts.values())


def test_rollups_follow_each_batch_and_a_resend(central: str, tmp_path: Path) -> None:
    work = line_runs(300, ["EOL-A", "EOL-B"], seed=21, root=Path("/runs"))
    local = ResultsDB(tmp_path / "local.sqlite")
    local.add_records([(r.folder, r.record) for r in work[:150]])
    sync = Sync(str(local.path), central, station_id="EOL-A", batch=BATCH)
    assert sync.push_once().sent == 150
    assert _compare(central) == 150
    local.add_records([(r.folder, r.record) for r in work[150:]])
    assert sync.push_once().sent == len(work) - 150  # retests of units sent before
    assert _compare(central) == len(work)
    with engine_for(central).connect() as con:
        before = kept_rollups(con)
        units = sum(c[6] for c in before[0].values())
        assert units == 300 and sum(c[9] for c in before[0].values()) > sum(
            c[8] for c in before[0].values())  # retests that passed moved units to final pass
    with local.engine.begin() as con:  # everything delivered again, as after a lost mark
        con.execute(outbox.update().values(sent_version=0))
    assert sync.push_once().sent == len(work)
    assert _compare(central) == len(work)
    with engine_for(central).connect() as con:
        assert kept_rollups(con) == before


def _at_revision(url: str, revision: str) -> None:
    from alembic import command
    from alembic.config import Config

    from station.db.connect import MIGRATIONS

    engine = sa.create_engine(url)
    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS))
    with engine.begin() as con:
        cfg.attributes["connection"] = con
        command.upgrade(cfg, revision)
    engine.dispose()


@pytest.mark.parametrize("revision", ["0005", "0006"])
def test_migration_fills_the_rollups_from_existing_runs(central: str, tmp_path: Path,
                                                        revision: str) -> None:
    """From schema 5 (no rollups: 0006 fills the hourly ones from the runs, 0007 the coarser
    ones from those) and from schema 6 (hourly rollups kept: 0007 fills the coarser)."""
    work = line_runs(120, ["EOL-A", "EOL-B"], seed=5, root=Path("/runs"))
    made = ResultsDB(tmp_path / "made.sqlite")  # the runs as the code of schema 5 wrote them
    made.add_records([(r.folder, r.record) for r in work])
    with made.engine.connect() as con:
        tables = {t: [dict(r) for r in con.execute(sa.text(f"SELECT * FROM {t}")).mappings()]
                  for t in ("runs", "measurements")}
    _at_revision(central, revision)
    old = sa.create_engine(central)
    with old.begin() as con:
        for table, rows in tables.items():
            names = list(rows[0])
            con.execute(sa.text(f"INSERT INTO {table} ({', '.join(names)}) VALUES "
                                f"({', '.join(':' + n for n in names)})"), rows)
        assert sa.inspect(con).has_table("rollup_runs") == (revision == "0006")
        assert not sa.inspect(con).has_table("rollup_runs_day_lot")
        if revision == "0006":
            add_hourly(con)  # what the sync of schema 6 kept
    old.dispose()
    assert _compare(central) == len(work)  # engine_for upgrades to head first
    with engine_for(central).connect() as con, made.engine.connect() as mine:
        assert kept_rollups(con) == kept_rollups(mine)


def test_a_test_delivered_late_moves_its_unit(central: str, tmp_path: Path) -> None:
    """A unit's earlier test arriving after its later one (two stations' syncs): the unit
    leaves the later test's hour, lot and verdict for the earlier one's."""
    late = line_record("U-LATE", "EOL-B", START + timedelta(hours=5), lot="LOT-2",
                       bias_dps=0.5)  # passes
    early = line_record("U-LATE", "EOL-A", START, lot="LOT-1", bias_dps=25.0)  # fails
    for i, rec in enumerate((late, early)):
        local = ResultsDB(tmp_path / f"local{i}.sqlite")
        local.add_records([(Path("/runs") / rec.run_id, rec)])
        assert Sync(str(local.path), central).push_once().sent == 1
        _compare(central)
    with engine_for(central).connect() as con:
        y = queries.yield_tables(con, Filters())
    assert [(r["group"], r["units"], r["tests"], r["first_pass"], r["final_pass"])
            for r in y["lot"]] == [("LOT-1", 1, 2, 0, 1)]


def test_latest_runs_come_a_page_at_a_time(tmp_path: Path) -> None:
    work = line_runs(70, ["EOL-A"], seed=3, root=Path("/runs"))
    db = ResultsDB(tmp_path / "line.sqlite")
    db.add_records([(r.folder, r.record) for r in work])
    with db.engine.connect() as con:
        first = queries.recent_runs(con, Filters(), limit=30)
        second = queries.recent_runs(con, Filters(), limit=30, before=first[-1]["started_utc"])
    newest = sorted(work, key=lambda r: r.record.started_utc, reverse=True)
    assert [r["run_id"] for r in first + second] == [r.record.run_id for r in newest[:60]]


@pytest.mark.parametrize("rows", [100, 3])
def test_yields_from_the_rollups_equal_a_count_over_the_runs(
        central: str, tmp_path: Path, rows: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every yield table the dashboard reads (simulated runs left out, then included)
    equals station.db.yields' GROUP BY over the runs themselves, its largest `rows` groups
    (the database sends no more, ties at the last included)."""
    monkeypatch.setattr(rolled, "YIELD_ROWS", rows)
    work = line_runs(200, ["EOL-A", "EOL-B", "EOL-C"], seed=17, root=Path("/runs"))
    sims = [line_record(f"SIM-{i}", "EOL-B", START + timedelta(hours=i), lot="LOT-000",
                        bias_dps=25.0, simulated=True) for i in range(12)]
    local = ResultsDB(tmp_path / "local.sqlite")
    local.add_records([(r.folder, r.record) for r in work]
                      + [(Path("/runs") / r.run_id, r) for r in sims])
    Sync(str(local.path), central, batch=BATCH).push_once()
    with engine_for(central).connect() as con:
        for include in (False, True):
            got = queries.yield_tables(con, Filters(include_simulated=include))
            for group in ("all", *GROUPS):
                direct = yields_by(con, None if group == "all" else group,
                                   include_simulated=include)
                assert [(r["group"], r["units"], r["tests"], r["first_pass"],
                         r["final_pass"]) for r in got[group]] == [
                    (y.group, y.units, y.tests, y.first_pass, y.final_pass)
                    for y in direct[:rows]]
            assert got["lot"][0]["units"] > 0 and got["shift"]
        left_out = queries.yield_tables(con, Filters())["all"][0]["units"]
        both = queries.yield_tables(con, Filters(include_simulated=True))["all"][0]["units"]
    assert both - left_out == len(sims)


def test_yields_over_whole_days_read_the_daily_rollups_and_equal_the_hourly(
        central: str, tmp_path: Path) -> None:
    """A range of whole days reads the daily rollups (an hour filter the hourly ones), and
    every yield table equals the answer read from the hourly rollup alone."""
    work = line_runs(400, ["EOL-A", "EOL-B", "EOL-C"], seed=29, root=Path("/runs"))
    local = ResultsDB(tmp_path / "local.sqlite")
    local.add_records([(r.folder, r.record) for r in work])
    Sync(str(local.path), central, batch=BATCH).push_once()
    days = [Filters(since="2026-11-02"), Filters(since="2026-11-03", until="2026-11-04"),
            Filters(since="2026-11-02", lot="LOT-003"), Filters(since="2026-11-02T17:00Z"),
            Filters(since="2026-11-02", product="ADIS16130-EOL", station="EOL-B")]
    with engine_for(central).connect() as con:
        for flt in days:
            sel = flt.selection(con)
            got = rolled.yield_tables(con, sel, DEFAULT_SHIFT_STARTS_H)
            assert got == rolled.yield_tables(con, sel, DEFAULT_SHIFT_STARTS_H, (rollup_runs,))
            assert got["all"] and got["shift"] and got["lot"]
        whole = Filters(since="2026-11-02").selection(con)
        assert rolled.pick(whole, RUN_ROLLUPS, ["lot"])[0].name == "rollup_runs_day_lot"
        assert rolled.pick(whole, RUN_ROLLUPS, ["station_id"])[0].name == (
            "rollup_runs_day_station")
        hours = Filters(since="2026-11-02T17:00Z").selection(con)
        assert rolled.pick(hours, RUN_ROLLUPS, ["lot"])[0] is rollup_runs
        assert rolled.pick(whole, MEASUREMENT_ROLLUPS, [])[0].name == (
            "rollup_measurements_day_product")
        daily = rolled.capabilities(con, whole, 0.95)
        hourly = rolled.capabilities(con, whole, 0.95, (rollup_measurements,))
    assert [c[:3] for c in daily] == [c[:3] for c in hourly] and daily
    for (*_, a), (*_, b) in zip(daily, hourly, strict=True):
        for field, value in asdict(a).items():  # sums in another order: the last bits
            other = asdict(b)[field]
            assert value == (pytest.approx(other, rel=1e-9, nan_ok=True)
                             if isinstance(other, float) else other), field
