"""A factory-scale line database in PostgreSQL, loaded with COPY (psycopg's cursor.copy()):
runs generated in Python chunk by chunk (numpy), never through the ORM.

16 stations, one run every STEP_S seconds, lots of 500 units, work orders of 5,000, two
products; about 8 % of first tests fail and most of those are retested at once; one run in
a hundred is simulated. Each run has 6 measurements; only the newest `keep_measurements`
runs keep theirs (as `station archive` retention leaves them): the older ones are summed into
the rollups from an unlogged staging table, then dropped. The indexes are dropped during the
load and built again after it; the rollups are filled by station.db.rollups' own backfills
(the hourly ones from the runs, as migration 0006 does; the coarser ones from the hourly, as
0007 does).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from datetime import UTC, datetime
from typing import Any

import numpy as np
import sqlalchemy as sa

from station.db import rollups

STEP_S = 3
STATIONS = 16
CHUNK = 200_000
T0 = datetime(2025, 1, 1, tzinfo=UTC)
RUN_COLUMNS = ("run_id", "serial", "product", "verdict", "simulated", "started_utc",
               "finished_utc", "station_id", "folder", "cal_bias_dps", "cal_scale",
               "work_order", "lot", "attempt", "first_run_id", "unit_verdict", "unit_tests")
MEAS_COLUMNS = ("run_id", "seq", "name", "condition", "value", "units", "low", "high",
                "outcome")
MEASURED = (("bias_dps", None, "deg/s", -10.0, 10.0), ("scale", None, "1", 0.94, 1.06),
            ("bias_dps", "T45_V5.25", "deg/s", -10.0, 10.0),
            ("scale", "T45_V5.25", "1", 0.94, 1.06),
            ("bias_temp_coeff_dps_per_c", "T25_V4.75", "deg/s/C", -0.03, 0.03),
            ("scale_temp_coeff_per_c", "T25_V4.75", "1/C", -5e-4, 5e-4))


def _chunk(rng: np.random.Generator, start: int, n: int, serial0: int, prev_fail: bool
           ) -> dict[str, Any]:
    """Runs start .. start+n: a run retests the unit before it when that first test failed
    (80 %); everything else is a new unit's first test."""
    fail_draw = rng.uniform(size=n) < 0.08
    retest_draw = rng.uniform(size=n) < 0.8
    retest = np.zeros(n, bool)
    verdict_fail = np.zeros(n, bool)
    last_fail = prev_fail
    for i in range(n):  # a short loop over booleans: the retest chain depends on the last run
        retest[i] = last_fail and retest_draw[i]
        verdict_fail[i] = retest_draw[i] < 0.08 if retest[i] else fail_draw[i]  # 10 %, 8 %
        last_fail = verdict_fail[i] and not retest[i]
    serial = serial0 + np.cumsum(~retest) - 1
    bias = rng.normal(0.0, 3.0, n)
    scale = 1 + rng.normal(0.0, 0.01, n)
    secs = (start + np.arange(n)) * STEP_S
    t = (np.datetime64(T0.replace(tzinfo=None)) + secs.astype("timedelta64[s]")).astype(str)
    return {"retest": retest, "fail": verdict_fail, "serial": serial, "bias": bias,
            "scale": scale, "t": t, "index": start + np.arange(n)}


def _rows(c: dict[str, Any], next_retest: np.ndarray, next_fail: np.ndarray) -> Iterator[str]:
    """COPY text lines of one chunk's runs (next_*: whether the following run retests each
    run's unit, and fails)."""
    for i in range(len(c["t"])):
        idx = int(c["index"][i])
        serial = f"S{int(c['serial'][i]):08d}"
        station = f"EOL-{idx % STATIONS:02d}"
        started = str(c["t"][i])
        run_id = f"{started.replace('-', '').replace(':', '')}Z_{station}_{serial}"
        retest = bool(c["retest"][i])
        unit_tests = 2 if retest or next_retest[i] else 1
        final_fail = next_fail[i] if next_retest[i] else c["fail"][i]
        first = (f"{_prev_id(started, idx)}" if retest else run_id)
        lot_n = int(c["serial"][i]) // 500
        yield "\t".join((
            run_id, serial, f"GYRO-{lot_n % 2}", "FAIL" if c["fail"][i] else "PASS",
            "1" if idx % 100 == 99 else "0", started + "+00:00", started + "+00:00",
            station, f"/runs/{run_id}", repr(float(c["bias"][i])), repr(float(c["scale"][i])),
            f"WO-{int(c['serial'][i]) // 5000:05d}", f"LOT-{lot_n:06d}",
            "2" if retest else "1", first, "FAIL" if final_fail else "PASS", str(unit_tests),
        )) + "\n"


def _prev_id(started: str, idx: int) -> str:
    """The run_id of the run before (a retest's unit's first test), from its index."""
    t = np.datetime64(T0.replace(tzinfo=None)) + np.timedelta64((idx - 1) * STEP_S, "s")
    text = str(t)
    # the serial is the same: the retest's own, filled in by the caller's format
    return f"{text.replace('-', '').replace(':', '')}Z_EOL-{(idx - 1) % STATIONS:02d}_"


def _measurement_lines(run_id: str, bias: float, scale: float, rng_vals: np.ndarray
                       ) -> Iterator[str]:
    for seq, (name, cond, units, lo, hi) in enumerate(MEASURED):
        v = bias if name == "bias_dps" else scale if name == "scale" else float(
            rng_vals[seq] * (hi - lo) / 12)
        yield (f"{run_id}\t{seq}\t{name}\t{cond or chr(92) + 'N'}\t{v!r}\t{units}\t{lo!r}\t"
               f"{hi!r}\t{'PASS' if lo <= v <= hi else 'FAIL'}\n")


def load(url: str, n_runs: int, keep_measurements: int, seed: int = 1) -> dict[str, float]:
    """Fill an empty, migrated database; returns the seconds each phase took."""
    import psycopg

    times: dict[str, float] = {}
    dsn = url.replace("postgresql+psycopg://", "postgresql://")
    t = time.perf_counter()
    with psycopg.connect(dsn, autocommit=True) as con:
        indexes = _drop_indexes(con)
        con.execute("CREATE UNLOGGED TABLE old_measurements (LIKE measurements)")
        _copy_all(con, n_runs, keep_measurements, seed)
        times["copy_s"] = time.perf_counter() - t
        t = time.perf_counter()
        for sql in indexes:
            con.execute(sql)
        con.execute("ANALYZE")
        times["index_s"] = time.perf_counter() - t
    t = time.perf_counter()
    engine = sa.create_engine(url)
    with engine.begin() as sacon:
        rollups.add_hourly(sacon)
        old = sa.Table("old_measurements", sa.MetaData(), autoload_with=sacon)
        rollups.add_measurements(sacon, old)
        sacon.exec_driver_sql("DROP TABLE old_measurements")
        times["hourly_rollups_s"] = time.perf_counter() - t
        rollups.fill_coarse(sacon)  # migration 0007's backfill
        times["coarse_rollups_s"] = time.perf_counter() - t - times["hourly_rollups_s"]
    with engine.connect() as sacon:
        sacon.execution_options(isolation_level="AUTOCOMMIT").exec_driver_sql("VACUUM ANALYZE")
    engine.dispose()
    times["rollups_s"] = time.perf_counter() - t
    return times


def _drop_indexes(con: Any) -> list[str]:
    """Drop the secondary indexes of runs and measurements; their CREATE statements."""
    rows = con.execute(
        "SELECT i.indexname, i.indexdef FROM pg_indexes i WHERE i.tablename IN "
        "('runs', 'measurements') AND i.indexname NOT IN "
        "(SELECT conname FROM pg_constraint)").fetchall()
    for name, _ in rows:
        con.execute(f'DROP INDEX "{name}"')
    return [sql for _, sql in rows]


def _copy_all(con: Any, n_runs: int, keep_measurements: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    serial0, prev_fail = 0, False
    runs_sql = f"COPY runs ({', '.join(RUN_COLUMNS)}) FROM STDIN"
    meas_cols = ", ".join(MEAS_COLUMNS)
    first_kept = n_runs - keep_measurements
    pending: dict[str, Any] | None = None
    for start in range(0, n_runs, CHUNK):
        c = _chunk(rng, start, min(CHUNK, n_runs - start), serial0, prev_fail)
        serial0 = int(c["serial"][-1]) + 1
        prev_fail = bool(c["fail"][-1] and not c["retest"][-1])
        if pending is not None:
            _write(con, pending, c, runs_sql, meas_cols, first_kept, rng)
        pending = c
    if pending is not None:
        _write(con, pending, None, runs_sql, meas_cols, first_kept, rng)


def _write(con: Any, c: dict[str, Any], after: dict[str, Any] | None, runs_sql: str,
           meas_cols: str, first_kept: int, rng: np.random.Generator) -> None:
    """COPY one chunk's runs and measurements (after: the next chunk, whose first run may
    retest this chunk's last unit)."""
    n = len(c["t"])
    nxt_retest = np.append(c["retest"][1:], after["retest"][0] if after else False)
    nxt_fail = np.append(c["fail"][1:], after["fail"][0] if after else False)
    lines = list(_rows(c, nxt_retest, nxt_fail))
    for i in np.nonzero(c["retest"])[0]:  # the retest's first run: the same serial
        lines[i] = _with_serial(lines[i])
    with con.cursor().copy(runs_sql) as copy:
        copy.write("".join(lines))
    vals = rng.normal(size=(n, len(MEASURED)))
    kept, old = [], []
    for i, line in enumerate(lines):
        run_id = line.split("\t", 1)[0]
        target = kept if int(c["index"][i]) >= first_kept else old
        target.extend(_measurement_lines(run_id, float(c["bias"][i]), float(c["scale"][i]),
                                         vals[i]))
    for table, rows in (("measurements", kept), ("old_measurements", old)):
        if rows:
            with con.cursor().copy(f"COPY {table} ({meas_cols}) FROM STDIN") as copy:
                copy.write("".join(rows))


def _with_serial(line: str) -> str:
    cells = line.split("\t")
    cells[14] += cells[1]  # first_run_id: the unit's first test's id ends with the serial
    return "\t".join(cells)
