"""The rollups computed directly from the runs and measurements (plain Python over the rows),
to compare with what station.db.rollups kept up to date."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import sqlalchemy as sa

from station.db.rollups import TIME_KEYS, grain
from station.db.schema import ROLLUP_KEY, RUN_COUNTS, rollup_measurements, rollup_runs

Key = tuple[Any, ...]
_VERDICTS = ("PASS", "FAIL", "ERROR", "ABORTED", "RUNNING")


def direct_rollups(con: sa.Connection, run_key: Sequence[str] = ROLLUP_KEY,
                   measurement_key: Sequence[str] = ROLLUP_KEY
                   ) -> tuple[dict[Key, tuple[int, ...]], dict[Key, tuple]]:
    """(run counts per run_key, measurement sums per measurement_key + name + condition) from
    the runs (a time key is the start's first hour or day)."""
    rows = con.execute(sa.text(
        "SELECT run_id, started_utc, station_id, product, lot, work_order, simulated, verdict,"
        " attempt, unit_verdict, unit_tests FROM runs")).mappings().all()
    counts: dict[Key, list[int]] = {}
    firsts: dict[str, Key] = {}
    for r in rows:
        c = counts.setdefault(_key(r, run_key), [0] * len(RUN_COUNTS))
        c[0] += 1
        c[1 + _VERDICTS.index(r["verdict"])] += 1
        if r["attempt"] == 1 and r["verdict"] != "RUNNING":
            firsts[r["run_id"]] = _key(r, measurement_key)
            c[6] += 1
            c[7] += r["unit_tests"]
            c[8] += r["verdict"] == "PASS"
            c[9] += r["unit_verdict"] == "PASS"
    sums: dict[Key, list[Any]] = {}
    for m in con.execute(sa.text("SELECT run_id, name, condition, value, low, high "
                                 "FROM measurements WHERE value IS NOT NULL")).mappings():
        key = firsts.get(m["run_id"])
        if key is None:
            continue
        s = sums.setdefault((*key, m["name"], m["condition"] or ""), [0, 0.0, 0.0, 0, 0])
        v = m["value"]
        s[0] += 1
        s[1] += v
        s[2] += v * v
        s[3] += m["low"] is not None and v < m["low"]
        s[4] += m["high"] is not None and v > m["high"]
    return ({k: tuple(v) for k, v in counts.items()},
            {k: (v[0], round(v[1], 6), round(v[2], 4), v[3], v[4]) for k, v in sums.items()})


def _key(run: Any, names: Sequence[str]) -> Key:
    return tuple(run["started_utc"][:TIME_KEYS[k]] if k in TIME_KEYS else run[k]
                 for k in names)


def kept_rollups(con: sa.Connection, run_table: sa.Table = rollup_runs,
                 measurement_table: sa.Table = rollup_measurements
                 ) -> tuple[dict[Key, tuple[int, ...]], dict[Key, tuple]]:
    """The same, read from rollup tables (keys whose counts fell to zero left out)."""
    run_key, measurement_key = grain(run_table), grain(measurement_table)
    counts = {
        tuple(r[k] for k in run_key): tuple(r[c] for c in RUN_COUNTS)
        for r in con.execute(sa.select(run_table)).mappings() if r["runs"]
    }
    sums = {
        (*[r[k] for k in measurement_key], r["name"], r["condition"]):
            (r["n"], round(r["total"], 6), round(r["total_sq"], 4), r["below"], r["above"])
        for r in con.execute(sa.select(measurement_table)).mappings() if r["n"]
    }
    return counts, sums
