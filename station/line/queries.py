"""What the line's dashboard shows, aggregated in SQL over the central database.

Everything is filtered by time (the first test's start), product, station and lot; the
counts come from the database (GROUP BY over indexed columns), not from loading runs.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from typing import Any

import sqlalchemy as sa

from station.db.schema import CAL_KEYS, measurements, runs, stations
from station.db.yields import DEFAULT_SHIFT_STARTS_H, GROUPS, yields_by
from station.line.spc import capability, western_electric
from station.results_db import parse_since

RECENT_RESULTS = 8


@dataclass(frozen=True)
class Filters:
    since: str | None = None
    until: str | None = None
    product: str | None = None
    station: str | None = None
    lot: str | None = None

    def clauses(self) -> list[sa.ColumnElement[bool]]:
        c: list[sa.ColumnElement[bool]] = []
        if self.since:
            c.append(runs.c.started_utc >= parse_since(self.since))
        if self.until:
            c.append(runs.c.started_utc < parse_since(self.until))
        if self.product:
            c.append(runs.c.product == self.product)
        if self.station:
            c.append(runs.c.station_id == self.station)
        if self.lot:
            c.append(runs.c.lot == self.lot)
        return c


def station_states(con: sa.Connection, offline_after_s: float, now: datetime | None = None
                   ) -> list[dict[str, Any]]:
    """Each station: its sync's last word (state, queued runs, when) and its latest results."""
    now = now or datetime.now(UTC)
    beats = {r.station_id: r for r in con.execute(sa.select(stations))}
    ids = set(beats) | set(con.scalars(sa.select(runs.c.station_id).group_by(runs.c.station_id)))
    out = []
    for sid in sorted(ids):
        recent = con.execute(
            sa.select(runs.c.run_id, runs.c.serial, runs.c.product, runs.c.verdict,
                      runs.c.started_utc, runs.c.attempt)
            .where(runs.c.station_id == sid)
            .order_by(runs.c.started_utc.desc()).limit(RECENT_RESULTS)
        ).mappings().all()
        beat = beats.get(sid)
        state, seen = "no sync", None
        if beat is not None:
            seen = beat.last_seen_utc
            age_s = (now - datetime.fromisoformat(seen)).total_seconds()
            state = beat.state if age_s <= offline_after_s else "offline"
        if recent and recent[0]["verdict"] == "RUNNING" and state in ("no sync", "idle"):
            state = "testing"
        out.append({
            "station_id": sid, "state": state, "last_seen_utc": seen,
            "pending_runs": beat.pending_runs if beat is not None else None,
            "recent": [dict(r) for r in recent],
        })
    return out


def yield_tables(con: sa.Connection, flt: Filters,
                 shift_starts_h: Sequence[int] = DEFAULT_SHIFT_STARTS_H) -> dict[str, Any]:
    where = flt.clauses()
    tables: dict[str, Any] = {"all": _yield_json(yields_by(con, None, where, shift_starts_h))}
    for group in GROUPS:
        tables[group] = _yield_json(yields_by(con, group, where, shift_starts_h))
    return tables


def _yield_json(rows: Sequence[Any]) -> list[dict[str, Any]]:
    return [
        {**asdict(r), "first_pass_yield": r.first_pass_yield, "final_yield": r.final_yield}
        for r in rows
    ]


def capabilities(con: sa.Connection, flt: Filters, confidence: float = 0.95
                 ) -> list[dict[str, Any]]:
    """Cpk of every limited measurement (per name and condition) over the units' first tests,
    with Bissell's interval. Mean and sd in two passes (no loss of precision)."""
    m, r = measurements.c, runs.c
    base = (
        sa.select(m.name, m.condition, m.value, m.low, m.high, m.units)
        .select_from(measurements.join(runs, r.run_id == m.run_id))
        .where(r.attempt == 1, r.verdict != "RUNNING", m.value.is_not(None), *flt.clauses())
        .subquery()
    )
    cond = sa.func.coalesce(base.c.condition, "")
    stats = (
        sa.select(base.c.name, cond.label("cond"), sa.func.count().label("n"),
                  sa.func.avg(base.c.value).label("mean"),
                  sa.func.min(base.c.low).label("low"), sa.func.max(base.c.high).label("high"),
                  sa.func.max(base.c.units).label("units"))
        .group_by(base.c.name, cond)
        .having(sa.or_(sa.func.min(base.c.low).is_not(None),
                       sa.func.max(base.c.high).is_not(None)))
        .subquery()
    )
    dev = base.c.value - stats.c.mean
    spread = (
        sa.select(stats, sa.func.sum(dev * dev).label("ss"))
        .select_from(base.join(stats, sa.and_(
            base.c.name == stats.c.name,
            cond == stats.c.cond)))
        .group_by(*stats.c)
    )
    out = []
    for row in con.execute(spread).mappings():
        n = int(row["n"])
        sd = math.sqrt(float(row["ss"]) / (n - 1)) if n > 1 else 0.0
        cap = capability(n, float(row["mean"]), sd, row["low"], row["high"], confidence)
        out.append({"name": row["name"], "condition": row["cond"], "units": row["units"],
                    **asdict(cap)})
    return sorted(out, key=lambda c: (c["name"], c["condition"]))


def control_chart(con: sa.Connection, flt: Filters, coefficient: str, limit: int = 200
                  ) -> dict[str, Any]:
    """An individuals chart of one calibration coefficient over the latest first tests:
    centre = mean, sigma = mean moving range / 1.128, Western Electric rules flagged."""
    if coefficient not in CAL_KEYS:
        raise ValueError(f"coefficient {coefficient!r}: choose one of {', '.join(CAL_KEYS)}")
    col = runs.c[f"cal_{coefficient}"]
    rows = con.execute(
        sa.select(runs.c.run_id, runs.c.serial, runs.c.started_utc, col.label("v"))
        .where(runs.c.attempt == 1, col.is_not(None), *flt.clauses())
        .order_by(runs.c.started_utc.desc()).limit(limit)
    ).all()[::-1]
    values = [float(r.v) for r in rows]
    centre = sum(values) / len(values) if values else 0.0
    ranges = [abs(b - a) for a, b in zip(values, values[1:], strict=False)]
    sigma = (sum(ranges) / len(ranges)) / 1.128 if ranges else 0.0
    flags = western_electric(values, centre, sigma)
    return {
        "coefficient": coefficient, "centre": centre, "sigma": sigma,
        "points": [
            {"run_id": r.run_id, "serial": r.serial, "started_utc": r.started_utc,
             "value": v, "rules": f}
            for r, v, f in zip(rows, values, flags, strict=True)
        ],
    }


def recent_runs(con: sa.Connection, flt: Filters, limit: int = 50) -> list[dict[str, Any]]:
    r = runs.c
    found = con.execute(
        sa.select(r.run_id, r.serial, r.product, r.station_id, r.lot, r.work_order, r.verdict,
                  r.attempt, r.started_utc)
        .where(*flt.clauses()).order_by(r.started_utc.desc()).limit(limit)
    ).mappings()
    return [dict(x) for x in found]


def choices(con: sa.Connection) -> dict[str, list[str]]:
    """Products, stations and lots to filter by (distinct values, index scans)."""
    return {
        name: [v for v in con.scalars(sa.select(col).group_by(col).order_by(col)) if v]
        for name, col in (("product", runs.c.product), ("station", runs.c.station_id),
                          ("lot", runs.c.lot))
    }


def run_folder(con: sa.Connection, run_id: str) -> str | None:
    return con.scalar(sa.select(runs.c.folder).where(runs.c.run_id == run_id))
