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


def _shift_by_hour(starts_h: Sequence[int]) -> dict[str, str]:
    """'00'..'23' -> the name of the shift that hour falls in."""
    hours = sorted(starts_h)
    if not hours or any(not 0 <= h < 24 for h in hours) or len(set(hours)) != len(hours):
        raise ValueError(f"shift start hours {list(starts_h)} must be distinct hours 0-23")
    names = shift_names(hours)
    out = {}
    for h in range(24):
        i = max((i for i, start in enumerate(hours) if start <= h), default=len(hours) - 1)
        out[f"{h:02d}"] = names[i]
    return out


def yield_tables(
    con: sa.Connection,
    where: Sequence[sa.ColumnElement[bool]] = (),
    shift_starts_h: Sequence[int] = DEFAULT_SHIFT_STARTS_H,
) -> dict[str, list[YieldRow]]:
    """Yield rows for all units ("all") and per station, product, lot, work order and shift,
    largest group first: one indexed pass over the units' first tests, rolled up here.

    where: filters on the runs table; they select the units by their first test."""
    # grouped by the hour (text), mapped to shifts here: cheaper than a CASE on every row
    hour = sa.func.substr(runs.c.started_utc, 12, 2).label("hour")
    keys = [runs.c.station_id.label("station"), runs.c.product, runs.c.lot, runs.c.work_order,
            hour]
    shift_at = _shift_by_hour(shift_starts_h)
    query = (
        sa.select(
            *keys,
            sa.func.count().label("units"),
            sa.func.sum(runs.c.unit_tests).label("tests"),
            sa.func.sum(sa.case((runs.c.verdict == "PASS", 1), else_=0)).label("fp"),
            sa.func.sum(sa.case((runs.c.unit_verdict == "PASS", 1), else_=0)).label("final"),
        )
        .where(runs.c.attempt == 1, runs.c.verdict != "RUNNING", *where)
        .group_by(*keys)
    )
    sums: dict[str, dict[str, list[int]]] = {g: {} for g in ("all", *GROUPS)}
    for found in con.execute(query).mappings():
        row = {**found, "shift": shift_at.get(found["hour"], "")}
        counts = [int(row["units"]), int(row["tests"] or 0), int(row["fp"] or 0),
                  int(row["final"] or 0)]
        for g in ("all", *GROUPS):
            acc = sums[g].setdefault("all" if g == "all" else str(row[g]), [0, 0, 0, 0])
            for i, c in enumerate(counts):
                acc[i] += c
    return {
        g: sorted((YieldRow(k, *v) for k, v in groups.items()), key=lambda y: (-y.units, y.group))
        for g, groups in sums.items()
    }


def yields_by(
    con: sa.Connection,
    group: str | None,
    where: Sequence[sa.ColumnElement[bool]] = (),
    shift_starts_h: Sequence[int] = DEFAULT_SHIFT_STARTS_H,
) -> list[YieldRow]:
    """Yield rows of one grouping (None: one row for all units); see yield_tables."""
    if group is not None and group not in GROUPS:
        raise ValueError(f"yield by {group!r}: choose one of {', '.join(GROUPS)}")
    return yield_tables(con, where, shift_starts_h)[group or "all"]
