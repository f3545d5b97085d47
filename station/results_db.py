"""The results database: one SQLite file indexing every run folder and its measurements.

The run folders stay the record of truth (record.json, raw data, certificate); the database
is an index for review (`station history`, `station lot-report`) and can be rebuilt from the
folders with `add_run`. Times are stored as ISO-8601 UTC text (`YYYY-MM-DDTHH:MM:SS+00:00`),
so text order is time order.

    db = ResultsDB(path)                      # creates the schema if missing
    db.add_run(run_folder, record)            # upsert by run_id, with all measurements
    db.runs(since=..., product=..., verdict=..., serial=...)
    db.measurement_values("bias_dps", product=...)
    db.mark_error(run_id, reason)             # a crashed run, found later
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, date, datetime
from pathlib import Path
from typing import Any

from procedures.record import RECORD_FILE, RunRecord, read_record

SCHEMA_VERSION = 1

_CAL_KEYS = (
    "bias_dps",
    "bias_temp_coeff_dps_per_c",
    "bias_supply_coeff_dps_per_v",
    "scale",
    "scale_temp_coeff_per_c",
    "scale_supply_coeff_per_v",
)

_SCHEMA = f"""
CREATE TABLE IF NOT EXISTS runs (
    run_id TEXT PRIMARY KEY,
    serial TEXT NOT NULL,
    product TEXT NOT NULL,
    verdict TEXT NOT NULL,
    reason TEXT NOT NULL DEFAULT '',
    failed_measurements TEXT NOT NULL DEFAULT '[]',
    simulated INTEGER NOT NULL DEFAULT 0,
    started_utc TEXT NOT NULL,
    finished_utc TEXT,
    station_id TEXT NOT NULL DEFAULT '',
    operator TEXT NOT NULL DEFAULT '',
    software_version TEXT NOT NULL DEFAULT '',
    procedure_name TEXT NOT NULL DEFAULT '',
    procedure_sha256 TEXT NOT NULL DEFAULT '',
    product_sha256 TEXT NOT NULL DEFAULT '',
    raw_sha256 TEXT NOT NULL DEFAULT '',
    folder TEXT NOT NULL,
    {", ".join(f"cal_{k} REAL, cal_{k}_u REAL" for k in _CAL_KEYS)}
);
CREATE INDEX IF NOT EXISTS runs_started ON runs(started_utc);
CREATE INDEX IF NOT EXISTS runs_serial ON runs(serial);
CREATE TABLE IF NOT EXISTS measurements (
    run_id TEXT NOT NULL REFERENCES runs(run_id) ON DELETE CASCADE,
    seq INTEGER NOT NULL,
    name TEXT NOT NULL,
    condition TEXT,
    value REAL,
    units TEXT NOT NULL DEFAULT '',
    low REAL,
    high REAL,
    marginal_low REAL,
    marginal_high REAL,
    outcome TEXT NOT NULL,
    uncertainty_k2 REAL,
    PRIMARY KEY (run_id, seq)
);
CREATE INDEX IF NOT EXISTS measurements_name ON measurements(name);
"""


class ResultsDBError(ValueError):
    """The database cannot be opened or a query is malformed; the message says what to do."""


@dataclass(frozen=True)
class RunRow:
    run_id: str
    serial: str
    product: str
    verdict: str
    reason: str
    failed_measurements: tuple[str, ...]
    simulated: bool
    started_utc: str
    finished_utc: str | None
    station_id: str
    operator: str
    software_version: str
    procedure_name: str
    procedure_sha256: str
    folder: str
    calibration: dict[str, float | None]  # coefficient key -> value (None when not written)


@dataclass(frozen=True)
class MeasurementRow:
    run_id: str
    serial: str
    started_utc: str
    verdict: str
    name: str
    condition: str | None
    value: float | None
    units: str
    low: float | None
    high: float | None
    outcome: str


def normalise_utc(text: str | None) -> str | None:
    """ISO-8601 text as `YYYY-MM-DDTHH:MM:SS+00:00` (naive times are taken as UTC)."""
    if text is None:
        return None
    try:
        t = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        return text
    if t.tzinfo is None:
        t = t.replace(tzinfo=UTC)
    return t.astimezone(UTC).isoformat(timespec="seconds")


def parse_since(value: str | date | datetime) -> str:
    """A --since argument (YYYY-MM-DD or ISO time) as normalised UTC text."""
    if isinstance(value, datetime):
        t = value if value.tzinfo else value.replace(tzinfo=UTC)
    elif isinstance(value, date):
        t = datetime(value.year, value.month, value.day, tzinfo=UTC)
    else:
        try:
            t = datetime.fromisoformat(value.strip().replace("Z", "+00:00"))
        except ValueError as exc:
            raise ResultsDBError(
                f"date {value!r} not understood: give YYYY-MM-DD or an ISO time such as "
                "2026-11-21T08:00:00Z"
            ) from exc
        if t.tzinfo is None:
            t = t.replace(tzinfo=UTC)
    return t.astimezone(UTC).isoformat(timespec="seconds")


class ResultsDB:
    """Index of run folders in an SQLite file; safe to open from several processes."""

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with self._connect() as con:
                con.executescript(_SCHEMA)
                con.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
        except (sqlite3.Error, OSError) as exc:
            raise ResultsDBError(
                f"{self.path}: cannot open the results database ({exc}); check the path and "
                "its permissions, or give another one with --db"
            ) from exc

    @contextmanager
    def _connect(self) -> Iterator[sqlite3.Connection]:
        con = sqlite3.connect(self.path, timeout=15.0)
        try:
            con.execute("PRAGMA foreign_keys = ON")
            with con:  # one transaction, committed or rolled back
                yield con
        finally:
            con.close()

    # ---- writing -----------------------------------------------------------------
    def add_run(self, run_folder: Path | str, record: RunRecord | None = None) -> None:
        """Index (or re-index) one run: replaces the run's row and all its measurements."""
        folder = Path(run_folder)
        rec = record if record is not None else read_record(folder)
        cal = rec.calibration
        cal_cols: dict[str, float | None] = {}
        for k in _CAL_KEYS:
            c = getattr(cal, k) if cal is not None else None
            cal_cols[f"cal_{k}"] = c.value if c is not None else None
            cal_cols[f"cal_{k}_u"] = c.uncertainty_k2 if c is not None else None
        row: dict[str, Any] = {
            "run_id": rec.run_id,
            "serial": rec.dut.serial,
            "product": rec.dut.product or rec.product.name or rec.product.path,
            "verdict": rec.verdict.value,
            "reason": rec.reason,
            "failed_measurements": json.dumps(list(rec.failed_measurements)),
            "simulated": int(rec.simulated),
            "started_utc": normalise_utc(rec.started_utc),
            "finished_utc": normalise_utc(rec.finished_utc),
            "station_id": str(rec.station.get("id", "")),
            "operator": rec.operator,
            "software_version": rec.software_version,
            "procedure_name": rec.procedure.name or rec.procedure.path,
            "procedure_sha256": rec.procedure.sha256,
            "product_sha256": rec.product.sha256,
            "raw_sha256": rec.raw_data.sha256 if rec.raw_data else "",
            "folder": str(folder.resolve()),
            **cal_cols,
        }
        cols = ", ".join(row)
        marks = ", ".join(f":{k}" for k in row)
        with self._connect() as con:
            con.execute("DELETE FROM measurements WHERE run_id = ?", (rec.run_id,))
            con.execute(f"INSERT OR REPLACE INTO runs ({cols}) VALUES ({marks})", row)
            con.executemany(
                "INSERT INTO measurements (run_id, seq, name, condition, value, units, low, "
                "high, marginal_low, marginal_high, outcome, uncertainty_k2) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                [
                    (rec.run_id, i, m.name, m.condition, m.value, m.units, m.low, m.high,
                     m.marginal_low, m.marginal_high, m.outcome.value, m.uncertainty_k2)
                    for i, m in enumerate(rec.measurements)
                ],
            )

    def reindex(self, root: Path | str) -> tuple[int, list[str]]:
        """Index every run folder under root (a folder holding record.json, any depth).

        Returns (number indexed, one line per folder that could not be read). A folder whose
        record is unreadable is skipped and reported, never guessed at.
        """
        added, problems = 0, []
        for record_path in sorted(Path(root).rglob(RECORD_FILE)):
            folder = record_path.parent
            try:
                self.add_run(folder, read_record(folder))
                added += 1
            except ValueError as exc:
                problems.append(str(exc))
        return added, problems

    def mark_error(self, run_id: str, reason: str) -> None:
        """Set a run's verdict to ERROR with the reason (e.g. a crash found on restart)."""
        with self._connect() as con:
            cur = con.execute(
                "UPDATE runs SET verdict = 'ERROR', reason = ? WHERE run_id = ?", (reason, run_id)
            )
            if cur.rowcount == 0:
                raise ResultsDBError(
                    f"run {run_id!r} is not in {self.path}; index its folder first (add_run)"
                )

    # ---- reading -----------------------------------------------------------------
    @staticmethod
    def _where(
        since: str | date | datetime | None,
        until: str | date | datetime | None,
        product: str | None,
        verdict: str | None,
        serial: str | None,
        prefix: str = "",
    ) -> tuple[str, list[Any]]:
        clauses, params = [], []
        if since is not None:
            clauses.append(f"{prefix}started_utc >= ?")
            params.append(parse_since(since))
        if until is not None:
            clauses.append(f"{prefix}started_utc < ?")
            params.append(parse_since(until))
        if product:
            clauses.append(f"{prefix}product = ?")
            params.append(product)
        if verdict:
            clauses.append(f"{prefix}verdict = ?")
            params.append(verdict.upper())
        if serial:
            clauses.append(f"{prefix}serial = ?")
            params.append(serial)
        return (" WHERE " + " AND ".join(clauses)) if clauses else "", params

    def runs(
        self,
        since: str | date | datetime | None = None,
        product: str | None = None,
        verdict: str | None = None,
        serial: str | None = None,
        until: str | date | datetime | None = None,
    ) -> list[RunRow]:
        """Runs matching every filter given, oldest first."""
        where, params = self._where(since, until, product, verdict, serial)
        with self._connect() as con:
            con.row_factory = sqlite3.Row
            rows = con.execute(
                f"SELECT * FROM runs{where} ORDER BY started_utc, run_id", params
            ).fetchall()
        return [
            RunRow(
                run_id=r["run_id"], serial=r["serial"], product=r["product"],
                verdict=r["verdict"], reason=r["reason"],
                failed_measurements=tuple(json.loads(r["failed_measurements"] or "[]")),
                simulated=bool(r["simulated"]), started_utc=r["started_utc"],
                finished_utc=r["finished_utc"], station_id=r["station_id"],
                operator=r["operator"], software_version=r["software_version"],
                procedure_name=r["procedure_name"], procedure_sha256=r["procedure_sha256"],
                folder=r["folder"], calibration={k: r[f"cal_{k}"] for k in _CAL_KEYS},
            )
            for r in rows
        ]

    def measurement_values(
        self,
        name: str | None = None,
        since: str | date | datetime | None = None,
        product: str | None = None,
        verdict: str | None = None,
        serial: str | None = None,
        until: str | date | datetime | None = None,
    ) -> list[MeasurementRow]:
        """Measurements (of one name, or all) of the runs matching the filters, oldest first."""
        where, params = self._where(since, until, product, verdict, serial, prefix="r.")
        if name is not None:
            where += (" AND" if where else " WHERE") + " m.name = ?"
            params.append(name)
        with self._connect() as con:
            rows = con.execute(
                "SELECT m.run_id, r.serial, r.started_utc, r.verdict, m.name, m.condition, "
                "m.value, m.units, m.low, m.high, m.outcome FROM measurements m "
                f"JOIN runs r ON r.run_id = m.run_id{where} "
                "ORDER BY r.started_utc, m.run_id, m.seq",
                params,
            ).fetchall()
        return [MeasurementRow(*r) for r in rows]

    def measurement_names(self, **filters: Any) -> list[str]:
        """Distinct measurement names, in the order they first appear in the oldest run."""
        seen: dict[str, None] = {}
        for m in self.measurement_values(**filters):
            seen.setdefault(m.name, None)
        return list(seen)
