"""Rollups: the runs counted per hour, station, product, lot, work order and simulated flag
(tables rollup_runs and rollup_measurements), kept up to date in the transaction that writes
the runs, so the dashboard reads them instead of the runs.

A batch of runs changes the rollups of its units only (a unit's first test, final verdict and
number of tests change when a retest arrives, or a run is delivered again). So the writer
subtracts what the runs of the batch's serials contributed before it writes (`subtract`), and
adds what they contribute afterwards (`add`): a run delivered twice is counted once, a retest
moves its unit from failed to passed. Each is one INSERT ... SELECT ... GROUP BY ... ON
CONFLICT DO UPDATE per chunk of serials, on PostgreSQL and SQLite alike.

Per key, rollup_runs counts runs by verdict, and the yields' units: finished first tests
(attempt 1), their tests, first passes and final passes (unit_verdict PASS).
rollup_measurements sums each measurement of those first tests: n, sum, sum of squares,
below/above its limits, and its extremes and widest limits. The extremes and the limits only
ever widen: a run leaving the rollup (a retest found to be earlier) does not narrow them.

The same counts and sums are kept at coarser grains (schema.RUN_ROLLUPS and
MEASUREMENT_ROLLUPS: per day and station, per day and lot, per hour and product...), by the
same statements grouped by each table's own key, in the same transaction. A filled hourly
rollup gives the coarser ones directly (`fill_coarse`: the backfill).
"""

from __future__ import annotations

import functools
from collections.abc import Collection, Iterable, Sequence
from typing import Any

import sqlalchemy as sa
from sqlalchemy.dialects import postgresql, sqlite

from station.db.schema import (
    MEASUREMENT_ROLLUPS,
    MEASUREMENT_SUMS,
    RUN_COUNTS,
    RUN_ROLLUPS,
    measurements,
    rollup_measurements,
    rollup_runs,
    runs,
)

_CHUNK = 500
# the time keys' text widths: YYYY-MM-DDTHH and YYYY-MM-DD (text order is time order)
TIME_KEYS = {"hour_utc": 13, "day_utc": 10}
_FINEST = (rollup_runs, rollup_measurements)


def subtract(con: sa.Connection, serials: Iterable[str]) -> None:
    """Take the runs of these serials out of the rollups (before they are rewritten)."""
    _apply(con, sorted(set(serials)), -1)


def add(con: sa.Connection, serials: Iterable[str]) -> None:
    """Count the runs of these serials into the rollups (after they are written)."""
    _apply(con, sorted(set(serials)), 1)


def add_hourly(con: sa.Connection) -> None:
    """Count every run into the empty hourly rollups (migration 0006's backfill)."""
    con.execute(_upsert(con.dialect.name, rollup_runs, _run_counts(rollup_runs, 1, ())))
    add_measurements(con, measurements)


def add_measurements(con: sa.Connection, values: sa.Table) -> None:
    """Sum the first tests' values in a table shaped like measurements (the measurements
    themselves, or a staging table of values no longer kept) into the hourly rollup."""
    con.execute(_upsert(con.dialect.name, rollup_measurements,
                        _measurement_sums(rollup_measurements, 1, (), values)))


def fill_coarse(con: sa.Connection, names: Collection[str] | None = None) -> None:
    """Fill the empty coarser rollups (those named, or all) from the hourly ones (migration
    0007's backfill: far fewer rows to read than the runs)."""
    for table in RUN_ROLLUPS + MEASUREMENT_ROLLUPS:
        if table not in _FINEST and (names is None or table.name in names):
            hourly = rollup_runs if table in RUN_ROLLUPS else rollup_measurements
            con.execute(_upsert(con.dialect.name, table, _rolled_up(table, hourly)))


def add_all(con: sa.Connection) -> None:
    """Count every run into every empty rollup."""
    add_hourly(con)
    fill_coarse(con)


def _apply(con: sa.Connection, serials: Sequence[str], sign: int) -> None:
    statements = _per_serials(con.dialect.name, sign)
    for i in range(0, len(serials), _CHUNK):
        for stmt in statements:
            con.execute(stmt, {"serials": serials[i : i + _CHUNK]})


@functools.cache
def _per_serials(dialect: str, sign: int) -> tuple[sa.Executable, ...]:
    """The statements counting the runs of some serials into every rollup (built once: the
    sync runs them for every 500 serials). PostgreSQL: one per kind (runs, measurements),
    the change to the hourly rollup computed once and summed into each grain; elsewhere one
    per rollup, each from the runs."""
    where = [runs.c.serial.in_(sa.bindparam("serials", expanding=True))]
    if dialect == "postgresql":
        return (_cascade(RUN_ROLLUPS, _run_counts(rollup_runs, sign, where)),
                _cascade(MEASUREMENT_ROLLUPS,
                         _measurement_sums(rollup_measurements, sign, where)))
    return (*[_upsert(dialect, t, _run_counts(t, sign, where)) for t in RUN_ROLLUPS],
            *[_upsert(dialect, t, _measurement_sums(t, sign, where))
              for t in MEASUREMENT_ROLLUPS])


def _cascade(tables: Sequence[sa.Table], hourly: sa.Select[Any]) -> sa.Select[Any]:
    """One statement: the hourly rows `hourly` selects (a WITH query), summed into each of
    the tables by data-modifying WITH queries (PostgreSQL)."""
    change = hourly.cte("change")
    into = [_upsert("postgresql", t, _rolled_up(t, change)).cte(f"into_{t.name}")
            for t in tables]
    return sa.select(sa.func.count()).select_from(change).add_cte(*into)


def grain(table: sa.Table) -> list[str]:
    """A rollup table's key: its time key, then its dimensions (not the measurement's name
    and condition)."""
    return [c.name for c in table.primary_key.columns if c.name not in ("name", "condition")]


def _time(started: sa.ColumnElement[str], name: str) -> sa.ColumnElement[Any]:
    return sa.func.substr(started, 1, TIME_KEYS[name]).label(name)


def _keys(table: sa.Table, source: sa.FromClause = runs) -> list[sa.ColumnElement[Any]]:
    """The table's key computed from a row of the source (the runs, or the hourly rollup)."""
    time = source.c.started_utc if source is runs else source.c.hour_utc
    return [_time(time, k) if k in TIME_KEYS else source.c[k] for k in grain(table)]


def _first_test() -> sa.ColumnElement[bool]:
    return sa.and_(runs.c.attempt == 1, runs.c.verdict != "RUNNING")


def _count(sign: int, cond: sa.ColumnElement[bool], value: Any = 1) -> Any:
    return sign * sa.func.sum(sa.case((cond, value), else_=0))


def _run_counts(table: sa.Table, sign: int, where: Sequence[sa.ColumnElement[bool]]
                ) -> sa.Select[Any]:
    v, first = runs.c.verdict, _first_test()
    counts = [
        sign * sa.func.count(),
        *[_count(sign, v == name) for name in ("PASS", "FAIL", "ERROR", "ABORTED", "RUNNING")],
        _count(sign, first), _count(sign, first, runs.c.unit_tests),
        _count(sign, sa.and_(first, v == "PASS")),
        _count(sign, sa.and_(first, runs.c.unit_verdict == "PASS")),
    ]
    keys = _keys(table)
    return (sa.select(*keys, *[c.label(n) for c, n in zip(counts, RUN_COUNTS, strict=True)])
            .where(*where).group_by(*keys).order_by(*keys))


def _measurement_sums(table: sa.Table, sign: int, where: Sequence[sa.ColumnElement[bool]],
                      values: sa.Table = measurements) -> sa.Select[Any]:
    m = values.c
    keys = [*_keys(table), m.name, sa.func.coalesce(m.condition, "").label("condition")]
    return (
        sa.select(
            *keys, sa.func.max(m.units).label("units"),
            (sign * sa.func.count()).label("n"), (sign * sa.func.sum(m.value)).label("total"),
            (sign * sa.func.sum(m.value * m.value)).label("total_sq"),
            _count(sign, m.value < m.low).label("below"),
            _count(sign, m.value > m.high).label("above"),
            sa.func.min(m.value).label("vmin"), sa.func.max(m.value).label("vmax"),
            sa.func.min(m.low).label("low"), sa.func.max(m.high).label("high"),
        )
        .select_from(runs.join(values, m.run_id == runs.c.run_id))
        .where(_first_test(), m.value.is_not(None), *where)
        .group_by(*keys).order_by(*keys)  # rows locked in one order by every writer
    )


def _rolled_up(table: sa.Table, source: sa.FromClause) -> sa.Select[Any]:
    """The table's rows summed from rows keyed like the hourly rollup of its kind (that
    rollup itself, or the change a batch makes to it)."""
    h = source.c
    keys = _keys(table, source)
    if table in RUN_ROLLUPS:
        values = [sa.func.sum(h[c]).label(c) for c in RUN_COUNTS]
    else:
        keys += [h.name, h.condition]
        values = [sa.func.sum(h[c]).label(c) for c in MEASUREMENT_SUMS]
        values += [sa.func.max(h.units).label("units"),
                   sa.func.min(h.vmin).label("vmin"), sa.func.max(h.vmax).label("vmax"),
                   sa.func.min(h.low).label("low"), sa.func.max(h.high).label("high")]
    return sa.select(*keys, *values).group_by(*keys).order_by(*keys)


def _upsert(dialect_name: str, table: sa.Table, select: sa.Select[Any]) -> sa.Insert:
    """INSERT the select's rows; a key already there gets them added (counts and sums) or
    widened (extremes and limits)."""
    dialect: Any = postgresql if dialect_name == "postgresql" else sqlite
    names = [c.name for c in select.selected_columns]
    stmt = dialect.insert(table).from_select(names, select)
    new = stmt.excluded
    sets: dict[str, Any] = {}
    for name in names:
        col = table.c[name]
        if col.primary_key:
            continue
        if name in (RUN_COUNTS if table in RUN_ROLLUPS else MEASUREMENT_SUMS):
            sets[name] = col + new[name]  # not a measurement's units (text): replaced
        elif name in ("vmin", "low"):
            sets[name] = _widest(col, new[name], lower=True)
        elif name in ("vmax", "high"):
            sets[name] = _widest(col, new[name], lower=False)
        else:
            sets[name] = new[name]
    return stmt.on_conflict_do_update(index_elements=list(table.primary_key.columns),
                                      set_=sets)


def _widest(old: Any, new: Any, *, lower: bool) -> Any:
    """The lower (or higher) of two bounds, either possibly NULL (no bound yet)."""
    better = new < old if lower else new > old
    return sa.case((old.is_(None), new), (new.is_(None), old), (better, new), else_=old)
