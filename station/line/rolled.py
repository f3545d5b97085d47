"""The dashboard's numbers read from the rollups (station/db/rollups.py), never the runs: the
rows read grow with the hours, stations, products and lots selected, not with the runs.
Without a start date, yields, stations and filter choices cover the latest YIELD_DAYS days
with runs, Cpk the latest CPK_DAYS.

The rollups count whole hours (UTC): a time filter selects the hours it starts in and the
hours it ends in (the page's filters are whole days). Shifts are groups of hours
(station.db.yields: the shift start hours, 06-14-22 UTC by default).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from datetime import datetime, timedelta
from typing import Any

import sqlalchemy as sa

from station.db.schema import rollup_measurements, rollup_runs
from station.db.yields import GROUPS, YieldRow, shift_by_hour
from station.line.spc import Capability, capability
from station.results_db import parse_since

YIELD_ROWS = 100  # the largest groups of a yield table (lots and work orders run to thousands)
CHOICE_LOTS = 500  # the latest lots offered as a filter
# Without a start date the panels cover the latest days there are runs in (a year of a busy
# line is 10^5 rollup rows: the default view reads a month's)
YIELD_DAYS = 30
CPK_DAYS = 7


def clauses(table: sa.Table, since: str | None, until: str | None, product: str | None,
            station: str | None, lot: str | None, include_simulated: bool
            ) -> list[sa.ColumnElement[bool]]:
    """The filters on a rollup table: the hours from since's to until's (whole hours)."""
    c = table.c
    out: list[sa.ColumnElement[bool]] = []
    if since:
        out.append(c.hour_utc >= parse_since(since)[:13])
    if until:
        end = parse_since(until)
        out.append(c.hour_utc < end[:13] if end[14:19] == "00:00" else c.hour_utc <= end[:13])
    for col, value in (("product", product), ("station_id", station), ("lot", lot)):
        if value:
            out.append(c[col] == value)
    if not include_simulated:
        out.append(c.simulated == 0)
    return out


_UNIT_SUMS = ("units", "unit_tests", "first_pass", "final_pass")


def yield_tables(con: sa.Connection, where: Sequence[sa.ColumnElement[bool]],
                 shift_starts_h: Sequence[int]) -> dict[str, list[YieldRow]]:
    """Yield rows for all units and per station, product, lot, work order and shift, largest
    group first (at most YIELD_ROWS per table). PostgreSQL: one pass over the rollups
    (GROUPING SETS); elsewhere one GROUP BY per table."""
    selected = [*where, rollup_runs.c.units > 0]
    if con.dialect.name == "postgresql":
        sums = _grouped_once(con, selected)
    else:
        sums = _grouped_each(con, selected)
    shift_at = shift_by_hour(shift_starts_h)
    shifts: dict[str, list[int]] = {}
    for hour, vals in sums.pop("hour").items():
        acc = shifts.setdefault(shift_at.get(hour, ""), [0, 0, 0, 0])
        for i, v in enumerate(vals):
            acc[i] += v
    sums["shift"] = shifts
    out = {g: sorted((YieldRow(k, *v) for k, v in groups.items()),
                     key=lambda y: (-y.units, y.group))[:YIELD_ROWS]
           for g, groups in sums.items()}
    assert set(out) == {"all", *GROUPS}
    return out


Sums = dict[str, dict[str, list[int]]]  # table -> group -> units, tests, first, final


def _dimensions() -> dict[str, sa.ColumnElement[Any]]:
    r = rollup_runs.c
    return {"station": r.station_id, "product": r.product, "lot": r.lot,
            "work_order": r.work_order, "hour": sa.func.substr(r.hour_utc, 12, 2)}


def _unit_sums() -> list[Any]:
    return [sa.func.sum(rollup_runs.c[k]) for k in _UNIT_SUMS]


def _grouped_each(con: sa.Connection, where: Sequence[sa.ColumnElement[bool]]) -> Sums:
    total = con.execute(sa.select(*_unit_sums()).where(*where)).one()
    out: Sums = {"all": {"all": [int(v) for v in total]} if total[0] else {}}
    for name, col in _dimensions().items():
        rows = con.execute(sa.select(col, *_unit_sums()).where(*where).group_by(col))
        out[name] = {str(k): [int(v) for v in vals] for k, *vals in rows}
    return out


def _grouped_once(con: sa.Connection, where: Sequence[sa.ColumnElement[bool]]) -> Sums:
    dims = _dimensions()
    cols = list(dims.values())
    sets = sa.func.grouping_sets(*[sa.tuple_(c) for c in cols], sa.text("()"))
    query = (sa.select(*cols, sa.func.grouping(*cols).label("g"), *_unit_sums())
             .where(*where).group_by(sets))
    out: Sums = {"all": {}, **{name: {} for name in dims}}
    bits = len(cols)
    for row in con.execute(query):
        keys, g, vals = row[:bits], row[bits], [int(v or 0) for v in row[bits + 1:]]
        if g == (1 << bits) - 1:  # the empty set: every unit (none when nothing matched)
            out["all"].update({"all": vals} if vals[0] else {})
            continue
        i = next(i for i in range(bits) if not g & (1 << (bits - 1 - i)))
        out[list(dims)[i]][str(keys[i])] = vals
    return out


def latest_days(con: sa.Connection, table: sa.Table, where: Sequence[sa.ColumnElement[bool]],
                since: str | None, days: int) -> list[sa.ColumnElement[bool]]:
    """Without a start: the latest `days` days of the selection (up to its newest hour, read
    along the table's key); with one, nothing more (the selection's own hours)."""
    if since:
        return []
    newest = con.scalar(sa.select(sa.func.max(table.c.hour_utc)).where(*where))
    if newest is None:
        return []
    start = datetime.fromisoformat(newest + ":00") - timedelta(days=days)
    return [table.c.hour_utc > start.isoformat(timespec="minutes")[:13]]


def capabilities(con: sa.Connection, where: Sequence[sa.ColumnElement[bool]],
                 confidence: float) -> list[tuple[str, str, str, Capability]]:
    """(name, condition, units, Cpk) of every measurement with limits, from the sums of
    its first tests' values in the rollups selected."""
    c = rollup_measurements.c
    rows = con.execute(
        sa.select(c.name, c.condition, sa.func.max(c.units), sa.func.sum(c.n),
                  sa.func.sum(c.total), sa.func.sum(c.total_sq), sa.func.min(c.vmin),
                  sa.func.max(c.vmax), sa.func.min(c.low), sa.func.max(c.high))
        .where(*where, c.n > 0).group_by(c.name, c.condition).order_by(c.name, c.condition)
    )
    out = []
    for name, condition, units, n, total, total_sq, vmin, vmax, low, high in rows:
        if low is None and high is None:
            continue  # informational: no limits, no capability
        mean, sd = pooled_mean_sd(int(n), float(total), float(total_sq), vmin == vmax)
        out.append((name, condition, units or "",
                    capability(int(n), mean, sd, low, high, confidence)))
    return out


def pooled_mean_sd(n: int, total: float, total_sq: float, constant: bool
                   ) -> tuple[float, float]:
    """Mean and sample sd from the count, sum and sum of squares (sd 0 when every value was
    the same: the sums' rounding is no spread)."""
    if n == 0:
        return math.nan, 0.0
    mean = total / n
    if n < 2 or constant:
        return mean, 0.0
    return mean, math.sqrt(max(0.0, (total_sq - total * mean) / (n - 1)))


def stations_seen(con: sa.Connection, where: Sequence[sa.ColumnElement[bool]]) -> set[str]:
    col = rollup_runs.c.station_id
    return set(con.scalars(sa.select(col).where(*where).group_by(col)))


def simulated_runs(con: sa.Connection, where: Sequence[sa.ColumnElement[bool]]) -> int:
    r = rollup_runs.c
    return int(con.scalar(sa.select(sa.func.sum(r.runs)).where(r.simulated != 0, *where))
               or 0)


def choices(con: sa.Connection, where: Sequence[sa.ColumnElement[bool]]
            ) -> dict[str, list[str]]:
    """Products, stations and the latest CHOICE_LOTS lots to filter by, in the hours
    selected."""
    r = rollup_runs.c
    out = {name: [v for v in con.scalars(sa.select(col).where(*where).group_by(col)
                                         .order_by(col)) if v]
           for name, col in (("product", r.product), ("station", r.station_id))}
    latest = (sa.select(r.lot).where(r.lot != "", *where).group_by(r.lot)
              .order_by(sa.func.max(r.hour_utc).desc()).limit(CHOICE_LOTS))
    out["lot"] = sorted(con.scalars(latest))
    return out
