"""First-pass yield and final yield, computed here and nowhere else (in SQL, over the runs).

A unit is a (product, serial). Its first test is its attempt 1; the unit counts
  - for first-pass yield when its first test PASSed,
  - for final yield when its latest test PASSed (unit_verdict),
and belongs to the station, lot, work order and shift of its first test. Every finished test
counts as an attempt: an ERROR or ABORTED first test is not a first pass. Runs still RUNNING
are left out, and so are simulated runs (`runs.simulated`: a bench simulator, no part)
unless asked for (include_simulated). Shifts are given as their starting hours in UTC
(default 06, 14, 22).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

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


def shift_by_hour(starts_h: Sequence[int]) -> dict[str, str]:
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
    include_simulated: bool = False,
) -> dict[str, list[YieldRow]]:
    """Yield rows for all units ("all") and per station, product, lot, work order and shift,
    largest group first. Two passes over the units' first tests, each reading one index in
    order (runs_groups): one grouped by station, product, lot and work order, rolled up here
    into the first five tables; one grouped by the hour of day, rolled up into shifts.

    where: filters on the runs table; they select the units by their first test.
    include_simulated: count simulated runs too (left out by default)."""
    first = (runs.c.attempt == 1, runs.c.verdict != "RUNNING", *where,
             *simulated_clauses(include_simulated))
    sums: dict[str, dict[str, list[int]]] = {g: {} for g in ("all", *GROUPS)}
    keys = [runs.c.station_id.label("station"), runs.c.product, runs.c.lot, runs.c.work_order]
    for row in con.execute(sa.select(*keys, *_COUNTS).where(*first).group_by(*keys)).mappings():
        for g in ("all", "station", "product", "lot", "work_order"):
            _add(sums[g], "all" if g == "all" else str(row[g]), row)
    hour = sa.func.substr(runs.c.started_utc, 12, 2)
    shift_at = shift_by_hour(shift_starts_h)
    for row in con.execute(sa.select(hour.label("hour"), *_COUNTS).where(*first)
                           .group_by(hour)).mappings():
        _add(sums["shift"], shift_at.get(row["hour"], ""), row)
    return {
        g: sorted((YieldRow(k, *v) for k, v in groups.items()), key=lambda y: (-y.units, y.group))
        for g, groups in sums.items()
    }


def simulated_clauses(include_simulated: bool) -> list[sa.ColumnElement[bool]]:
    """The clause leaving simulated runs out (none when they are included)."""
    return [] if include_simulated else [runs.c.simulated == 0]


_COUNTS = (
    sa.func.count().label("units"),
    sa.func.sum(runs.c.unit_tests).label("tests"),
    sa.func.sum(sa.case((runs.c.verdict == "PASS", 1), else_=0)).label("fp"),
    sa.func.sum(sa.case((runs.c.unit_verdict == "PASS", 1), else_=0)).label("final"),
)


def _add(groups: dict[str, list[int]], key: str, row: Any) -> None:
    acc = groups.setdefault(key, [0, 0, 0, 0])
    for i, name in enumerate(("units", "tests", "fp", "final")):
        acc[i] += int(row[name] or 0)


def yields_by(
    con: sa.Connection,
    group: str | None,
    where: Sequence[sa.ColumnElement[bool]] = (),
    shift_starts_h: Sequence[int] = DEFAULT_SHIFT_STARTS_H,
    include_simulated: bool = False,
) -> list[YieldRow]:
    """Yield rows of one grouping (None: one row for all units); see yield_tables."""
    if group is not None and group not in GROUPS:
        raise ValueError(f"yield by {group!r}: choose one of {', '.join(GROUPS)}")
    return yield_tables(con, where, shift_starts_h, include_simulated)[group or "all"]
