"""The line's database: sync throughput and lag, and the dashboard's load time over 10^5 runs.

  - sync throughput: runs per second pushed by one `Sync.push_once` from a station's local
    SQLite to the central database (records with their measurements);
  - sync lag: seconds from a run's end (indexed locally, sync woken, as UutRunner does) to
    the run being readable in the central database, with the sync thread running;
  - dashboard load: the five requests the page makes at once (/api/stations, yields,
    capability, runs, chart) over HTTP against a central database of --runs runs (default
    100000, 12 measurements each, 4 stations, lots, retests), cold (first) and warm (median of
    the next 3), wall and CPU time (the CPU time is the cost without other load on the
    machine), and each request alone; with --browser also the page in chromium until it has
    drawn everything. Target: 1 s.

    python3 benchmarks/bench_line_db.py [--runs 100000] [--sync-runs 2000] [--postgres]
                                        [--browser] [--keep /tmp/line-100k.sqlite]
    python3 benchmarks/bench_line_db.py --sync [--sync-runs 10000] [--batch 1000] [--postgres]
    python3 benchmarks/bench_line_db.py --postgres --copy --runs 1000000 [--keep-measurements N]

--copy (with --postgres): the factory-scale dashboard. A throwaway PostgreSQL loaded with COPY
(benchmarks/line_copy.py: --runs runs, the measurements of the newest --keep-measurements,
default all up to 10^6, older ones only in the rollups); prints the load's time and
pg_database_size, then each dashboard request (signed in, through the real app served by
uvicorn) --repeat times: its p50 and p95 on loopback (target 300 ms), and the page drawn in
chromium (target 1 s).

--postgres runs the sync part against a throwaway PostgreSQL server (Debian's postgresql).
--sync measures the sync alone (no dashboard): one station's outbox of --sync-runs parts
(about 10% more runs: retests), 6 measurements each, pushed in batches of --batch runs;
besides the wall time, the CPU time of this process and of the PostgreSQL server's processes
(runs per CPU second: what the machine's load does not change).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from datetime import UTC, datetime, timedelta
from functools import partial
from pathlib import Path
from typing import Any

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import sqlalchemy as sa  # noqa: E402

from station.db.connect import engine_for  # noqa: E402
from station.db.schema import (  # noqa: E402
    CAL_KEYS,
    MEASUREMENT_ROLLUPS,
    RUN_ROLLUPS,
    measurements,
    runs,
)
from station.db.sync import Sync, SyncThread  # noqa: E402
from station.results_db import ResultsDB  # noqa: E402
from station.ui.server import serve_in_thread  # noqa: E402
from tests.linedb.linekit import (  # noqa: E402
    line_app,
    line_record,
    line_runs,
    sign_in,
    sign_in_page,
)

TARGET_S = 1.0
NAMES = [("bias_dps", "deg/s", -10.0, 10.0), ("scale", "1", 0.94, 1.06),
         ("bias_temp_coeff_dps_per_c", "deg/s/C", -0.03, 0.03),
         ("scale_temp_coeff_per_c", "1/C", -5e-4, 5e-4)]
CONDITIONS = [None, "T25_V4.75", "T45_V5.25"]


def build_big(path: Path, n_runs: int, seed: int = 1) -> None:
    """n_runs synthetic runs written straight into the tables (attempts computed here)."""
    rng = np.random.default_rng(seed)
    db = ResultsDB(path)
    t0 = datetime(2026, 1, 1, tzinfo=UTC)
    run_rows: list[dict[str, Any]] = []
    meas_rows: list[dict[str, Any]] = []
    first_of: dict[str, tuple[str, int]] = {}
    last_verdict: dict[str, str] = {}
    serial_i = 0
    for i in range(n_runs):
        retest = first_of and rng.uniform() < 0.05
        serial = (list(first_of)[-int(rng.integers(1, min(50, len(first_of)) + 1))]
                  if retest else f"B{serial_i:07d}")
        if not retest:
            serial_i += 1
        started = (t0 + timedelta(seconds=40 * i)).isoformat(timespec="seconds")
        station = f"EOL-{'ABCD'[i % 4]}"
        run_id = f"{started[:19].replace('-', '').replace(':', '')}Z_{station}_{serial}"
        bias = float(rng.normal(0, 4.0))
        scale = float(1 + rng.normal(0, 0.015))
        verdict = "PASS" if abs(bias) < 10 and 0.94 < scale < 1.06 else "FAIL"
        first, attempt = first_of.get(serial, (run_id, 0))
        first_of[serial] = (first, attempt + 1)
        last_verdict[serial] = verdict
        row: dict[str, Any] = {
            "run_id": run_id, "serial": serial, "product": "ADIS16130-EOL", "verdict": verdict,
            "started_utc": started, "finished_utc": started, "station_id": station,
            "folder": f"/runs/{run_id}", "lot": f"LOT-{serial_i // 500:04d}",
            "work_order": f"WO-{serial_i // 2000}", "attempt": attempt + 1,
            "first_run_id": first, "unit_verdict": "",
        }
        for k in CAL_KEYS:
            row[f"cal_{k}"] = bias if k == "bias_dps" else scale if k == "scale" else 0.0
            row[f"cal_{k}_u"] = 0.01
        run_rows.append(row)
        seq = 0
        for cond in CONDITIONS:
            for name, units, lo, hi in NAMES:
                v = bias if name == "bias_dps" else scale if name == "scale" else float(
                    rng.normal(0, (hi - lo) / 12))
                meas_rows.append({"run_id": run_id, "seq": seq, "name": name, "condition": cond,
                                  "value": v, "units": units, "low": lo, "high": hi,
                                  "outcome": "PASS" if lo <= v <= hi else "FAIL"})
                seq += 1
    for row in run_rows:
        row["unit_verdict"] = last_verdict[row["serial"]]
        row["unit_tests"] = first_of[row["serial"]][1]
    with db.engine.begin() as con:
        for i in range(0, len(run_rows), 5000):
            con.execute(runs.insert(), run_rows[i : i + 5000])
        for i in range(0, len(meas_rows), 20000):
            con.execute(measurements.insert(), meas_rows[i : i + 20000])
    with db.engine.begin() as con:
        con.exec_driver_sql("ANALYZE")


def bench_dashboard(path: Path, browser: bool) -> dict[str, float]:
    db = ResultsDB(path)
    server = serve_in_thread(line_app(db.engine))  # signed in as an engineer below
    paths = ["/api/stations", "/api/yields", "/api/capability", "/api/runs",
             "/api/chart?coefficient=bias_dps"]
    out: dict[str, float] = {}
    try:
        with httpx.Client(base_url=server.url, timeout=60) as client:
            sign_in(client)
            times, cpu = [], []
            for _ in range(4):
                t, c = time.perf_counter(), time.process_time()
                with ThreadPoolExecutor(len(paths)) as pool:  # as the page asks: at once
                    for r in pool.map(client.get, paths):
                        r.raise_for_status()
                times.append(time.perf_counter() - t)
                cpu.append(time.process_time() - c)
            out["api_cold_s"] = times[0]
            out["api_warm_s"] = statistics.median(times[1:])
            out["api_warm_cpu_s"] = statistics.median(cpu[1:])  # all requests' CPU, summed
            for p in paths:
                t, c = time.perf_counter(), time.process_time()
                client.get(p).raise_for_status()
                out[f"{p.split('?')[0]}_s"] = time.perf_counter() - t
                out[f"{p.split('?')[0]}_cpu_s"] = time.process_time() - c
            t = time.perf_counter()
            client.get("/api/yields", params={"product": "ADIS16130-EOL",
                                              "since": "2026-02-10"}).raise_for_status()
            out["api_yields_last_days_s"] = time.perf_counter() - t
        if browser:
            out["browser_page_s"] = _median_page_load(server.url, loads=3)
    finally:
        server.stop()
    return out


def server_cpu_s(data: Path) -> float:
    """CPU seconds used so far by a PostgreSQL server's processes (the postmaster's
    children: the backends and the background writers)."""
    postmaster = int((data / "postmaster.pid").read_text().split()[0])
    ticks = 0
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:  # ended meanwhile
            continue
        if int(fields[1]) == postmaster:
            ticks += int(fields[11]) + int(fields[12])  # utime, stime
    return ticks / os.sysconf("SC_CLK_TCK")


def bench_sync(folder: Path, n_runs: int, central: str, batch: int,
               server_cpu: Callable[[], float]) -> dict[str, float]:
    local = ResultsDB(folder / "local.sqlite")
    work = line_runs(n_runs, ["EOL-A"], seed=9, root=folder / "runs")
    local.add_records([(r.folder, r.record) for r in work])
    sync = Sync(str(local.path), central, station_id="EOL-A", batch=batch)
    engine_for(sync.central_url)  # the schema created before the clock starts
    t, cpu, server = time.perf_counter(), time.process_time(), server_cpu()
    report = sync.push_once()
    elapsed = time.perf_counter() - t
    cpu, server = time.process_time() - cpu, server_cpu() - server
    n_meas = sum(len(r.record.measurements) for r in work)
    # lag: one run at a time, as a station finishes them, with the sync thread running
    thread = SyncThread(sync, interval_s=1.0).start()
    central_engine = engine_for(sync.central_url)
    lags = []
    t_run = datetime(2027, 1, 1, tzinfo=UTC)
    try:
        for i in range(20):
            rec = line_record(f"LAG-{i:03d}", "EOL-A", t_run + timedelta(minutes=i))
            t = time.perf_counter()
            local.add_run(folder / "runs" / rec.run_id, rec)
            thread.wake()
            while True:
                with central_engine.connect() as con:
                    if con.scalar(sa.select(runs.c.run_id).where(runs.c.run_id == rec.run_id)):
                        break
                time.sleep(0.002)
            lags.append(time.perf_counter() - t)
            time.sleep(0.05)
    finally:
        thread.stop()
    return {"sync_runs": report.sent, "sync_measurements": n_meas, "sync_batch": batch,
            "sync_s": elapsed, "sync_runs_per_s": report.sent / elapsed,
            # the work itself, whatever else the machine runs: this process and the server
            "sync_cpu_s": cpu, "sync_server_cpu_s": server,
            "sync_runs_per_cpu_s": report.sent / (cpu + server),
            "lag_median_s": statistics.median(lags), "lag_max_s": max(lags)}


def dashboard(args: argparse.Namespace, tmp: Path) -> dict[str, float]:
    big = args.keep or tmp / "line.sqlite"
    if not big.exists():
        t = time.perf_counter()
        build_big(big, args.runs)
        print(f"built {args.runs} runs in {time.perf_counter() - t:.1f} s", file=sys.stderr)
    return bench_dashboard(big, args.browser)


REQUEST_TARGET_S = 0.3
DASHBOARD_PATHS = ("/api/stations", "/api/yields", "/api/capability", "/api/runs",
                   "/api/chart?coefficient=bias_dps", "/api/yields?since=2025-01-20",
                   "/api/stations?since=2025-01-20", "/api/capability?since=2025-01-20",
                   "/api/capability?lot=LOT-000100", "/api/runs?lot=LOT-000100",
                   "/api/chart?coefficient=scale&station=EOL-03")


def bench_copy(url: str, n_runs: int, keep: int, repeat: int) -> dict[str, Any]:
    """Load --runs runs by COPY, then time every dashboard request and the page."""
    from benchmarks.line_copy import load

    engine = engine_for(url)  # migrated to head: the tables and indexes the app expects
    t = time.perf_counter()
    out: dict[str, Any] = {"runs": n_runs, "runs_with_measurements": keep}
    out.update(load(url, n_runs, keep))
    out["load_s"] = time.perf_counter() - t
    with engine.connect() as con:
        out["database_bytes"] = int(con.scalar(sa.text(
            "SELECT pg_database_size(current_database())")) or 0)
        out["rollup_rows"] = {t.name: int(con.scalar(sa.select(sa.func.count()).select_from(t))
                                          or 0) for t in (*RUN_ROLLUPS, *MEASUREMENT_ROLLUPS)}
    print(f"loaded {n_runs} runs in {out['load_s']:.0f} s, "
          f"{out['database_bytes'] / 1e9:.2f} GB", file=sys.stderr)
    out["requests"] = _request_times(engine, repeat)
    out["browser_page_s"] = _page_times(engine)
    return out


def _request_times(engine: Any, repeat: int) -> dict[str, dict[str, float]]:
    server = serve_in_thread(line_app(engine))
    out = {}
    try:
        with httpx.Client(base_url=server.url, timeout=60) as client:
            sign_in(client)
            for p in DASHBOARD_PATHS:
                client.get(p).raise_for_status()  # the first (cold) answer is not counted
                times = []
                for _ in range(repeat):
                    t = time.perf_counter()
                    client.get(p).raise_for_status()
                    times.append(time.perf_counter() - t)
                q = statistics.quantiles(times, n=20, method="inclusive")
                out[p] = {"p50_s": statistics.median(times), "p95_s": q[18],
                          "max_s": max(times)}
                print(f"{p}: p95 {q[18] * 1000:.0f} ms", file=sys.stderr)
    finally:
        server.stop()
    return out


def _median_page_load(url: str, loads: int) -> float:
    """The dashboard drawn in chromium, signed in: the median of `loads` page loads (s)."""
    from station.ui.headless import chromium, wait_js

    with chromium() as b:
        page = b.new_page()
        sign_in_page(page, url)  # the session cookie stays for the loads below
        times = []
        for _ in range(loads):
            t = time.perf_counter()
            page.goto(url)
            wait_js(page, "document.body.dataset.loaded === '1'", timeout_s=60)
            times.append(time.perf_counter() - t)
    return statistics.median(times)


def _page_times(engine: Any) -> float:
    server = serve_in_thread(line_app(engine))
    try:
        return _median_page_load(server.url, loads=5)
    finally:
        server.stop()


def copy_main(args: argparse.Namespace) -> int:
    from tests.linedb.pgserver import PgServer, missing_reason

    reason = missing_reason()
    if reason:
        print(f"--postgres: {reason}", file=sys.stderr)
        return 2
    server = PgServer()
    server.start()
    try:
        keep = min(args.runs, args.keep_measurements)
        results = bench_copy(server.url, args.runs, keep, args.repeat)
    finally:
        from station.db.connect import dispose_all

        dispose_all()
        server.destroy()
    results["request_target_s"] = REQUEST_TARGET_S
    results["page_target_s"] = TARGET_S
    print(json.dumps(results, indent=2))
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=100_000)
    ap.add_argument("--sync-runs", type=int, default=2000)
    ap.add_argument("--sync", action="store_true", help="the sync alone, no dashboard")
    ap.add_argument("--batch", type=int, default=Sync.BATCH, help="runs per sync batch")
    ap.add_argument("--postgres", action="store_true", help="sync into a real PostgreSQL")
    ap.add_argument("--browser", action="store_true", help="also time the page in chromium")
    ap.add_argument("--keep", type=Path, help="the big database file (reused when present)")
    ap.add_argument("--copy", action="store_true",
                    help="with --postgres: load --runs by COPY and time the dashboard")
    ap.add_argument("--keep-measurements", type=int, default=1_000_000,
                    help="with --copy: the newest runs that keep their measurements")
    ap.add_argument("--repeat", type=int, default=40, help="with --copy: times per request")
    args = ap.parse_args()
    if args.copy:
        if not args.postgres:
            ap.error("--copy loads PostgreSQL: give --postgres too")
        return copy_main(args)
    results: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        if not args.sync:
            results["dashboard"] = dashboard(args, Path(tmp))
        server = None
        if args.postgres:
            from tests.linedb.pgserver import PgServer, missing_reason

            reason = missing_reason()
            if reason:
                print(f"--postgres: {reason}", file=sys.stderr)
                return 2
            server = PgServer()
            server.start()
            central = server.url
        else:
            central = f"sqlite:///{Path(tmp) / 'central.sqlite'}"
        try:
            cpu = partial(server_cpu_s, server.data) if server else lambda: 0.0
            results["sync"] = bench_sync(Path(tmp), args.sync_runs, central, args.batch, cpu)
            results["sync"]["central"] = "postgresql" if server else "sqlite"
        finally:
            if server is not None:
                server.destroy()
    if not args.sync:
        results["runs"] = args.runs
        results["dashboard_target_s"] = TARGET_S
    print(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
