"""What the line's dashboard shows, over the central database.

Everything is filtered by time (the first test's start), product, station and lot, and
leaves simulated runs out unless they are asked for. Yields, Cpk, the stations and the
filter choices are read from the rollups (station/line/rolled.py: rows per hour, not per
run); the latest runs and the control chart read a bounded number of runs along an index.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from typing import Any

import sqlalchemy as sa

from station.db.schema import CAL_KEYS, measurements, rollup_measurements, rollup_runs, runs
from station.db.schema import stations as station_table
from station.db.yields import DEFAULT_SHIFT_STARTS_H, simulated_clauses
from station.line import rolled
from station.line.spc import western_electric
from station.results_db import parse_since

RECENT_RESULTS = 8
COEFFICIENT_UNITS = {"bias_dps": "deg/s", "bias_temp_coeff_dps_per_c": "deg/s/C",
                     "bias_supply_coeff_dps_per_v": "deg/s/V", "scale": "1",
                     "scale_temp_coeff_per_c": "1/C", "scale_supply_coeff_per_v": "1/V"}
CPK_WINDOW = f"first tests of the selected days (without a start: the latest {rolled.CPK_DAYS})"
RUN_PAGE = 50  # the latest runs, a page at a time


@dataclass(frozen=True)
class Filters:
    since: str | None = None
    until: str | None = None
    product: str | None = None
    station: str | None = None
    lot: str | None = None
    include_simulated: bool = False  # simulated runs are no production: left out by default

    def where(self) -> list[sa.ColumnElement[bool]]:
        """The chosen selection, and simulated runs left out unless included."""
        return [*self.clauses(), *simulated_clauses(self.include_simulated)]

    def clauses(self) -> list[sa.ColumnElement[bool]]:
        """The chosen selection: time, product, station, lot."""
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

    def selection(self, con: sa.Connection, days: int = rolled.YIELD_DAYS,
                  table: sa.Table = rollup_runs) -> rolled.Selection:
        """The selection on the rollups, limited to the latest `days` days with runs (in
        this hourly rollup) when no start is given."""
        sel = rolled.Selection(self.since, self.until, self.product, self.station, self.lot,
                               self.include_simulated)
        return rolled.latest_days(con, sel, days, table)


def station_states(con: sa.Connection, offline_after_s: float, now: datetime | None = None,
                   include_simulated: bool = False) -> list[dict[str, Any]]:
    """Each station: its sync's last word (state, queued runs, when) and its latest results
    (simulated runs left out unless included: a station never heard from with none left is
    not shown)."""
    now = now or datetime.now(UTC)
    real = simulated_clauses(include_simulated)
    beats = {r.station_id: r for r in con.execute(sa.select(station_table))}
    seen = Filters(include_simulated=True).selection(con)
    ids = set(beats) | rolled.stations_seen(con, seen)
    out = []
    for sid in sorted(ids):
        recent = con.execute(
            sa.select(runs.c.run_id, runs.c.serial, runs.c.product, runs.c.verdict,
                      runs.c.started_utc, runs.c.attempt)
            .where(runs.c.station_id == sid, *real)
            .order_by(runs.c.started_utc.desc()).limit(RECENT_RESULTS)
        ).mappings().all()
        beat = beats.get(sid)
        if beat is None and not recent:
            continue  # only simulated runs, left out
        state = _state(beat, recent, now, offline_after_s)
        out.append({
            "station_id": sid, "state": state,
            "last_seen_utc": beat.last_seen_utc if beat is not None else None,
            "pending_runs": beat.pending_runs if beat is not None else None,
            "recent": [dict(r) for r in recent],
        })
    return out


def _state(beat: Any, recent: Sequence[Any], now: datetime, offline_after_s: float) -> str:
    """From the sync's last word (offline when older than offline_after_s), testing when
    the latest run is still running."""
    state = "no sync"
    if beat is not None:
        age_s = (now - datetime.fromisoformat(beat.last_seen_utc)).total_seconds()
        state = beat.state if age_s <= offline_after_s else "offline"
    if recent and recent[0]["verdict"] == "RUNNING" and state in ("no sync", "idle"):
        state = "testing"
    return state


def yield_tables(con: sa.Connection, flt: Filters,
                 shift_starts_h: Sequence[int] = DEFAULT_SHIFT_STARTS_H) -> dict[str, Any]:
    tables = rolled.yield_tables(con, flt.selection(con), shift_starts_h)
    return {group: _yield_json(rows) for group, rows in tables.items()}


def _yield_json(rows: Sequence[Any]) -> list[dict[str, Any]]:
    return [
        {**asdict(r), "first_pass_yield": r.first_pass_yield, "final_yield": r.final_yield}
        for r in rows
    ]


def capabilities(con: sa.Connection, flt: Filters, confidence: float = 0.95
                 ) -> list[dict[str, Any]]:
    """Cpk of every limited measurement (per name and condition) over the first tests of the
    selected days (the latest CPK_DAYS without a start), with Bissell's interval, from the
    rollups' sums."""
    sel = flt.selection(con, rolled.CPK_DAYS, rollup_measurements)
    return [{"name": name, "condition": condition, "units": units, **asdict(cap)}
            for name, condition, units, cap in rolled.capabilities(con, sel, confidence)]


@dataclass(frozen=True)
class ChartPoint:
    run_id: str
    serial: str
    started_utc: str
    value: float
    rules: list[int]  # the Western Electric rules this point completes


@dataclass(frozen=True)
class ControlChart:
    """An individuals chart: centre = mean, sigma = mean moving range / 1.128, control limits
    centre +/- 3 sigma (rule 1's line); product limits the measurement's low/high, if any."""
    coefficient: str
    units: str
    centre: float
    sigma: float
    ucl: float
    lcl: float
    product_low: float | None
    product_high: float | None
    points: list[ChartPoint]


def control_chart(con: sa.Connection, flt: Filters, coefficient: str, limit: int = 200
                  ) -> dict[str, Any]:
    """The individuals chart of one calibration coefficient over the latest first tests,
    Western Electric rules flagged, with the product's limits of that measurement."""
    if coefficient not in CAL_KEYS:
        raise ValueError(f"coefficient {coefficient!r}: choose one of {', '.join(CAL_KEYS)}")
    col = runs.c[f"cal_{coefficient}"]
    rows = con.execute(
        sa.select(runs.c.run_id, runs.c.serial, runs.c.started_utc, col.label("v"))
        .where(runs.c.attempt == 1, col.is_not(None), *flt.where())
        .order_by(runs.c.started_utc.desc()).limit(limit)
    ).all()[::-1]
    values = [float(r.v) for r in rows]
    centre = sum(values) / len(values) if values else 0.0
    ranges = [abs(b - a) for a, b in zip(values, values[1:], strict=False)]
    sigma = (sum(ranges) / len(ranges)) / 1.128 if ranges else 0.0
    flags = western_electric(values, centre, sigma)
    low, high = product_limits(con, coefficient, [r.run_id for r in rows])
    points = [ChartPoint(r.run_id, r.serial, r.started_utc, v, f)
              for r, v, f in zip(rows, values, flags, strict=True)]
    return asdict(ControlChart(coefficient, COEFFICIENT_UNITS[coefficient], centre, sigma,
                               centre + 3 * sigma, centre - 3 * sigma, low, high, points))


def product_limits(con: sa.Connection, name: str, run_ids: Sequence[str]
                   ) -> tuple[float | None, float | None]:
    """The widest low and high limits the runs' measurement `name` was judged against."""
    if not run_ids:
        return None, None
    m = measurements.c
    low, high = con.execute(
        sa.select(sa.func.min(m.low), sa.func.max(m.high))
        .where(m.name == name, m.run_id.in_(run_ids))
    ).one()
    return (None if low is None else float(low)), (None if high is None else float(high))


def recent_runs(con: sa.Connection, flt: Filters, limit: int = RUN_PAGE,
                before: str | None = None) -> list[dict[str, Any]]:
    """The latest runs of the selection, newest first; `before` (a run's started_utc, the
    last of a page) gives the next page. One index range, whatever the runs."""
    r = runs.c
    page = [r.started_utc < parse_since(before)] if before else []
    found = con.execute(
        sa.select(r.run_id, r.serial, r.product, r.station_id, r.lot, r.work_order, r.verdict,
                  r.attempt, r.started_utc)
        .where(*flt.where(), *page).order_by(r.started_utc.desc()).limit(limit)
    ).mappings()
    return [dict(x) for x in found]


def simulated_left_out(con: sa.Connection, flt: Filters) -> int:
    """How many simulated runs the selection leaves out (0 when they are included)."""
    if flt.include_simulated:
        return 0
    every = Filters(**{**asdict(flt), "include_simulated": True})
    return rolled.simulated_runs(con, every.selection(con))


def choices(con: sa.Connection, flt: Filters) -> dict[str, list[str]]:
    """Products, stations and lots to filter by: those of the selected days (from the
    rollups)."""
    days = Filters(since=flt.since, until=flt.until, include_simulated=True)
    return rolled.choices(con, days.selection(con))


def run_folder(con: sa.Connection, run_id: str) -> str | None:
    return con.scalar(sa.select(runs.c.folder).where(runs.c.run_id == run_id))
