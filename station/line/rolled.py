"""The dashboard's numbers read from the rollups (station/db/rollups.py), never the runs: the
rows read grow with the hours, stations, products and lots selected, not with the runs.
Without a start date, yields, stations and filter choices cover the latest YIELD_DAYS days
with runs, Cpk the latest CPK_DAYS.

The rollups count whole hours (UTC): a time filter selects the hours it starts in and the
hours it ends in (the page's filters are whole days). Shifts are groups of hours
(station.db.yields: the shift start hours, 06-14-22 UTC by default). Each query reads the
coarsest rollup that answers it (`pick`): a range of whole days reads the daily rollups,
whose rows do not grow with the stations a lot passes or the hours of a day.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from datetime import datetime, timedelta
from typing import Any

import sqlalchemy as sa

from station.db.rollups import TIME_KEYS
from station.db.schema import MEASUREMENT_ROLLUPS, RUN_ROLLUPS, rollup_runs
from station.db.yields import GROUPS, YieldRow, shift_by_hour
from station.line.spc import Capability, capability
from station.results_db import parse_since

YIELD_ROWS = 100  # the largest groups of a yield table (lots and work orders run to thousands)
CHOICE_LOTS = 500  # the latest lots offered as a filter
# Without a start date the panels cover the latest days there are runs in (a year of a busy
# line is 10^5 rollup rows: the default view reads a month's)
YIELD_DAYS = 30
CPK_DAYS = 7
Where = list[sa.ColumnElement[bool]]


@dataclass(frozen=True)
class Selection:
    """What a panel selects: from since to until (times as parse_since reads them), product,
    station, lot; simulated runs left out unless included."""
    since: str | None = None
    until: str | None = None
    product: str | None = None
    station: str | None = None
    lot: str | None = None
    include_simulated: bool = False

    def where(self, table: sa.Table) -> Where | None:
        """The filters on a rollup table, or None when it cannot say them: a dimension it
        does not keep, a time inside one of its days. An hourly table selects the hours since
        and until fall in."""
        c, out = table.c, []
        for col, value in (("product", self.product), ("station_id", self.station),
                           ("lot", self.lot)):
            if value and col not in c:
                return None
            if value:
                out.append(c[col] == value)
        key = "hour_utc" if "hour_utc" in c else "day_utc"
        for bound, after in ((self.since, True), (self.until, False)):
            if not bound:
                continue
            t, width = parse_since(bound), TIME_KEYS[key]
            whole = not t[width:19].strip("T:0")  # the bound starts an hour (a day)
            if not whole and key == "day_utc":
                return None
            out.append(c[key] >= t[:width] if after else
                       c[key] < t[:width] if whole else c[key] <= t[:width])
        if not self.include_simulated:
            out.append(c.simulated == 0)
        return out


def pick(sel: Selection, tables: Sequence[sa.Table], columns: Sequence[str]
         ) -> tuple[sa.Table, Where]:
    """The coarsest of the rollup tables (coarsest first) that has these columns and can say
    the selection, and its filters."""
    for table in tables:
        where = sel.where(table) if all(k in table.c for k in columns) else None
        if where is not None:
            return table, where
    raise AssertionError(f"no rollup answers {columns} for {sel}")


def latest_days(con: sa.Connection, sel: Selection, days: int,
                table: sa.Table = rollup_runs) -> Selection:
    """Without a start: the selection from the hour after its newest hour less `days` days
    (read along the hourly table's key); with one, the selection as it is."""
    where = sel.where(table)
    if sel.since or where is None:
        return sel
    newest = con.scalar(sa.select(sa.func.max(table.c.hour_utc)).where(*where))
    if newest is None:
        return sel
    start = datetime.fromisoformat(newest + ":00") - timedelta(days=days, hours=-1)
    return replace(sel, since=start.isoformat())


_UNIT_SUMS = ("units", "unit_tests", "first_pass", "final_pass")
# each yield table's column in the rollups ("all": none; the shift is read from the hour)
_DIMENSIONS = {"all": "", "station": "station_id", "product": "product", "lot": "lot",
               "work_order": "work_order", "hour": "hour_utc"}


def yield_tables(con: sa.Connection, sel: Selection, shift_starts_h: Sequence[int],
                 tables: Sequence[sa.Table] = RUN_ROLLUPS) -> dict[str, list[YieldRow]]:
    """Yield rows for all units and per station, product, lot, work order and shift, largest
    group first (at most YIELD_ROWS per table), each from the coarsest rollup that answers
    it (of `tables`, coarsest first). PostgreSQL: one pass over each rollup read (GROUPING
    SETS); elsewhere one GROUP BY per table."""
    plan: dict[sa.Table, tuple[list[str], Where]] = {}
    for name, col in _DIMENSIONS.items():
        table, where = pick(sel, tables, [col] if col else [])
        plan.setdefault(table, ([], where))[0].append(name)
    sums: Sums = {}
    for table, (names, where) in plan.items():
        selected = [*where, table.c.units > 0]
        if con.dialect.name == "postgresql" and len(names) > 2:
            sums.update(_grouped_once(con, table, names, selected))
        else:
            sums.update(_grouped_each(con, table, names, selected))
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


def _column(table: sa.Table, name: str) -> sa.ColumnElement[Any]:
    col = table.c[_DIMENSIONS[name]]
    return sa.func.substr(col, 12, 2) if name == "hour" else col


def _unit_sums(table: sa.Table) -> list[Any]:
    return [sa.func.sum(table.c[k]) for k in _UNIT_SUMS]


def _grouped_each(con: sa.Connection, table: sa.Table, names: Sequence[str],
                  where: Where) -> Sums:
    out: Sums = {}
    for name in names:
        if name == "all":
            total = con.execute(sa.select(*_unit_sums(table)).where(*where)).one()
            out["all"] = {"all": [int(v) for v in total]} if total[0] else {}
            continue
        col = _column(table, name)
        query = sa.select(col, *_unit_sums(table)).where(*where).group_by(col)
        rows = (con.execute(query) if name == "hour"  # every hour: the shifts add them up
                else _largest(con, query.add_columns(_rank(table, None, sa.false()))))
        out[name] = {str(k): [int(v) for v in vals] for k, *vals in rows}
    return out


def _grouped_once(con: sa.Connection, table: sa.Table, names: Sequence[str],
                  where: Where) -> Sums:
    dims = [n for n in names if n != "all"]
    cols = [_column(table, n) for n in dims]
    sets = sa.func.grouping_sets(*[sa.tuple_(c) for c in cols], sa.text("()"))
    g = sa.func.grouping(*cols)
    bits = len(cols)
    hours = (1 << bits) - 1 - (1 << (bits - 1 - dims.index("hour"))) if "hour" in dims else -1
    query = (sa.select(*cols, g.label("g"), *_unit_sums(table), _rank(table, g, g == hours))
             .where(*where).group_by(sets))
    out: Sums = {name: {} for name in names}
    for row in _largest(con, query):
        keys, g, vals = row[:bits], row[bits], [int(v or 0) for v in row[bits + 1:]]
        if g == (1 << bits) - 1:  # the empty set: every unit (none when nothing matched)
            if "all" in out:
                out["all"].update({"all": vals} if vals[0] else {})
            continue
        i = next(i for i in range(bits) if not g & (1 << (bits - 1 - i)))
        out[dims[i]][str(keys[i])] = vals
    return out


def _rank(table: sa.Table, partition: Any, every: Any) -> sa.ColumnElement[Any]:
    """A group's rank by units, largest first (ties share it): the groups ranked within
    YIELD_ROWS are the largest YIELD_ROWS and every group tied with the last of them (all
    of them where `every`: the hours, which the shifts add up)."""
    units = sa.case((every, 0), else_=sa.func.sum(table.c.units))
    return sa.func.rank().over(partition_by=partition, order_by=units.desc()).label("rank")


def _largest(con: sa.Connection, query: sa.Select[Any]) -> list[Any]:
    """The query's rows ranked within YIELD_ROWS (its last column, the rank, left off): a
    year's thousands of lots are not sent to Python to keep a hundred."""
    ranked = query.subquery()
    return [row[:-1] for row in con.execute(
        sa.select(ranked).where(ranked.c["rank"] <= YIELD_ROWS))]


def capabilities(con: sa.Connection, sel: Selection, confidence: float,
                 tables: Sequence[sa.Table] = MEASUREMENT_ROLLUPS
                 ) -> list[tuple[str, str, str, Capability]]:
    """(name, condition, units, Cpk) of every measurement with limits, from the sums of
    its first tests' values in the coarsest measurement rollup (of `tables`, coarsest first)
    that answers the selection."""
    table, where = pick(sel, tables, [])
    c = table.c
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


def stations_seen(con: sa.Connection, sel: Selection) -> set[str]:
    table, where = pick(sel, RUN_ROLLUPS, ["station_id"])
    col = table.c.station_id
    return set(con.scalars(sa.select(col).where(*where).group_by(col)))


def simulated_runs(con: sa.Connection, sel: Selection) -> int:
    table, where = pick(sel, RUN_ROLLUPS, [])
    return int(con.scalar(sa.select(sa.func.sum(table.c.runs))
                          .where(table.c.simulated != 0, *where)) or 0)


def choices(con: sa.Connection, sel: Selection) -> dict[str, list[str]]:
    """Products, stations and the latest CHOICE_LOTS lots (by their latest hour, or day
    over whole days) to filter by, in the times selected."""
    out = {}
    for name, key in (("product", "product"), ("station", "station_id")):
        table, where = pick(sel, RUN_ROLLUPS, [key])
        col = table.c[key]
        out[name] = [v for v in con.scalars(sa.select(col).where(*where).group_by(col)
                                            .order_by(col)) if v]
    table, where = pick(sel, RUN_ROLLUPS, ["lot"])
    r = table.c
    time = r.hour_utc if "hour_utc" in r else r.day_utc
    latest = (sa.select(r.lot).where(r.lot != "", *where).group_by(r.lot)
              .order_by(sa.func.max(time).desc(), r.lot.desc()).limit(CHOICE_LOTS))
    out["lot"] = sorted(con.scalars(latest))
    return out
