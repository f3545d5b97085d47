"""First-pass yield and final yield, computed here and nowhere else (in SQL, over the runs).

A unit is a (product, serial). Its first test is its attempt 1; the unit counts
  - for first-pass yield when its first test PASSed,
  - for final yield when its latest test PASSed (unit_verdict),
and belongs to the station, lot, work order and shift of its first test. Every finished test
counts as an attempt: an ERROR or ABORTED first test is not a first pass. Runs still RUNNING
are left out. Shifts are given as their starting hours in UTC (default 06, 14, 22).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import sqlalchemy as sa

from station.db.schema import runs

GROUPS = ("station", "product", "lot", "work_order", "shift")
DEFAULT_SHIFT_STARTS_H = (6, 14, 22)


@dataclass(frozen=True)
class YieldRow:
    group: str  # the station id, product, lot, ... ("" when not recorded)
    units: int  # distinct serials first tested in this group
    tests: int  # all tests of those units (first tests and retests)
    first_pass: int  # units that passed their first test
    final_pass: int  # units whose latest test passed

    @property
    def first_pass_yield(self) -> float | None:
        return self.first_pass / self.units if self.units else None

    @property
    def final_yield(self) -> float | None:
        return self.final_pass / self.units if self.units else None


def shift_names(starts_h: Sequence[int]) -> list[str]:
    hours = sorted(starts_h)
    return [
        f"{chr(ord('A') + i)} {h:02d}-{hours[(i + 1) % len(hours)]:02d}"
        for i, h in enumerate(hours)
    ]


def shift_of(started_utc: sa.ColumnElement[str], starts_h: Sequence[int]) -> sa.ColumnElement[str]:
    """SQL: the shift a time falls in (hours from the ISO text, portable SQLite/PostgreSQL)."""
    hours = sorted(starts_h)
    if not hours or any(not 0 <= h < 24 for h in hours) or len(set(hours)) != len(hours):
        raise ValueError(f"shift start hours {list(starts_h)} must be distinct hours 0-23")
    names = shift_names(hours)
    hour = sa.cast(sa.func.substr(started_utc, 12, 2), sa.Integer)
    whens = [
        (sa.and_(hour >= h, hour < hours[i + 1]), names[i]) for i, h in enumerate(hours[:-1])
    ]
    return sa.case(*whens, else_=names[-1]) if whens else sa.literal(names[0])


def group_column(
    group: str, starts_h: Sequence[int] = DEFAULT_SHIFT_STARTS_H
) -> sa.ColumnElement[str]:
    if group == "station":
        return runs.c.station_id
    if group in ("product", "lot", "work_order"):
        return runs.c[group]
    if group == "shift":
        return shift_of(runs.c.started_utc, starts_h)
    raise ValueError(f"yield by {group!r}: choose one of {', '.join(GROUPS)}")


def yields_by(
    con: sa.Connection,
    group: str | None,
    where: Sequence[sa.ColumnElement[bool]] = (),
    shift_starts_h: Sequence[int] = DEFAULT_SHIFT_STARTS_H,
) -> list[YieldRow]:
    """Yield rows per group (or one row for all when group is None), largest group first.

    where: filters on the runs table; they select the units by their first test."""
    key = group_column(group, shift_starts_h) if group else sa.literal("all")
    finished = runs.c.verdict != "RUNNING"
    first = (
        sa.select(
            key.label("g"),
            sa.func.count().label("units"),
            sa.func.sum(sa.case((runs.c.verdict == "PASS", 1), else_=0)).label("fp"),
            sa.func.sum(sa.case((runs.c.unit_verdict == "PASS", 1), else_=0)).label("final"),
        )
        .where(runs.c.attempt == 1, finished, *where)
        .group_by(key)
    )
    later = sa.alias(runs, "later")
    tests = (
        sa.select(key.label("g"), sa.func.count().label("tests"))
        .select_from(runs.join(later, later.c.first_run_id == runs.c.run_id))
        .where(runs.c.attempt == 1, finished, later.c.verdict != "RUNNING", *where)
        .group_by(key)
    )
    counts = {r.g: int(r.tests) for r in con.execute(tests)}
    found = [
        YieldRow(group=str(r.g), units=int(r.units), tests=counts.get(r.g, int(r.units)),
                 first_pass=int(r.fp or 0), final_pass=int(r.final or 0))
        for r in con.execute(first)
    ]
    return sorted(found, key=lambda y: (-y.units, y.group))
