"""The results database: every run folder and its measurements, indexed (SQLAlchemy).

The run folders stay the record of truth (record.json, raw data, certificate); the database
is an index for review (`station history`, `station lot-report`, the line's dashboard) and can
be rebuilt from the folders with `add_run`. It is a SQLite file by default and may be any
database SQLAlchemy reaches by URL (PostgreSQL for a line); the schema is migrated with alembic
when the database is opened (station/db/migrations). Times are ISO-8601 UTC text
(`YYYY-MM-DDTHH:MM:SS+00:00`), so text order is time order.

    db = ResultsDB(path_or_url)               # creates or migrates the schema
    db.add_run(run_folder, record)            # upsert by run_id, with all measurements
    db.runs(since=..., product=..., verdict=..., serial=..., lot=..., work_order=...)
    db.measurement_values("bias_dps", product=...)
    db.mark_error(run_id, reason)             # a crashed run, found later
    db.relocate(run_id, folder)               # its files moved (an archive)
"""

from __future__ import annotations

import json
from collections.abc import Callable
from datetime import UTC, date, datetime
from pathlib import Path
from typing import Any, TypeVar

import sqlalchemy as sa
from sqlalchemy.exc import SQLAlchemyError

from procedures.runtime.record import RECORD_FILE, RunRecord, read_record
from reports.lot_rows import CalibrationElement, MeasurementRow, RunRow
from station.db.connect import DatabaseError, database_url, engine_for, shown, sqlite_path
from station.db.schema import CAL_KEYS, calibration_elements, measurements, runs
from station.db.store import (
    element_rows,
    measurement_rows,
    normalise_utc,
    replace_runs,
    run_row,
)

SCHEMA_VERSION = 5
T = TypeVar("T")
__all__ = ["CalibrationElement", "MeasurementRow", "ResultsDB", "ResultsDBError", "RunRow",
           "normalise_utc",
           "parse_since"]


class ResultsDBError(DatabaseError):
    """The database cannot be opened or a query is malformed; the message says what to do."""


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


When = str | date | datetime | None


def run_filters(
    since: When = None,
    until: When = None,
    product: str | None = None,
    verdict: str | None = None,
    serial: str | None = None,
    lot: str | None = None,
    work_order: str | None = None,
) -> list[sa.ColumnElement[bool]]:
    """WHERE clauses on the runs table for the usual filters (all optional)."""
    clauses: list[sa.ColumnElement[bool]] = []
    if since is not None:
        clauses.append(runs.c.started_utc >= parse_since(since))
    if until is not None:
        clauses.append(runs.c.started_utc < parse_since(until))
    if product:
        clauses.append(runs.c.product == product)
    if verdict:
        clauses.append(runs.c.verdict == verdict.upper())
    if serial:
        clauses.append(runs.c.serial == serial)
    if lot:
        clauses.append(runs.c.lot == lot)
    if work_order:
        clauses.append(runs.c.work_order == work_order)
    return clauses


class ResultsDB:
    """Index of run folders in a database; safe to open from several processes and threads."""

    def __init__(self, path: Path | str, base: Path | None = None) -> None:
        try:
            self.url = database_url(path, base)
            self.engine = engine_for(self.url)
        except DatabaseError as exc:
            raise ResultsDBError(f"{exc}; or give another one with --db") from None
        file = sqlite_path(self.url)
        # a SQLite file's path; for a server, its URL without the password
        self.path: Path | str = file if file is not None else shown(self.url)

    def _begin(self) -> Any:
        return self.engine.begin()

    def _read(self, read: Callable[[sa.Connection], T]) -> T:
        """`read(connection)`, a database error as ResultsDBError."""
        try:
            with self.engine.connect() as con:
                return read(con)
        except SQLAlchemyError as exc:
            raise self._fail(exc) from None

    def _fail(self, exc: Exception) -> ResultsDBError:
        return ResultsDBError(
            f"{shown(self.url)}: results database error ({exc.__class__.__name__}: "
            f"{str(exc).splitlines()[0]}); check that the database is reachable and writable"
        )

    # ---- writing -----------------------------------------------------------------
    def add_run(self, run_folder: Path | str, record: RunRecord | None = None) -> None:
        """Index (or re-index) one run: replaces the run's row and all its measurements, and
        queues it for the line's central database."""
        folder = Path(run_folder)
        rec = record if record is not None else read_record(folder)
        self.add_records([(folder, rec)])

    def add_records(self, items: list[tuple[Path, RunRecord]]) -> None:
        """Index several runs in one transaction (as add_run)."""
        rows = [run_row(folder, rec) for folder, rec in items]
        meas = [m for _, rec in items for m in measurement_rows(rec)]
        elements = [e for _, rec in items for e in element_rows(rec)]
        try:
            with self._begin() as con:
                replace_runs(con, rows, meas, queue=True, elements=elements)
        except SQLAlchemyError as exc:
            raise self._fail(exc) from None

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
        self._rewrite(run_id, {"verdict": "ERROR", "reason": reason})

    def relocate(self, run_id: str, folder: str) -> None:
        """Point a run's row at where its files are now (`station archive`: ARCHIVE#RUN,
        station/run_archive.py), queued for the line's central database like any change."""
        self._rewrite(run_id, {"folder": folder})

    def _rewrite(self, run_id: str, changes: dict[str, Any]) -> None:
        try:
            with self._begin() as con:
                found = con.execute(
                    sa.select(runs).where(runs.c.run_id == run_id)).mappings().first()
                if found is None:
                    raise ResultsDBError(
                        f"run {run_id!r} is not in {self.path}; index its folder first (add_run)"
                    )
                full = {**found, **changes}
                meas = [dict(m) for m in con.execute(
                    sa.select(measurements).where(measurements.c.run_id == run_id)
                ).mappings()]
                elements = [dict(e) for e in con.execute(
                    sa.select(calibration_elements).where(
                        calibration_elements.c.run_id == run_id)).mappings()]
                replace_runs(con, [full], meas, queue=True, elements=elements)
        except SQLAlchemyError as exc:
            raise self._fail(exc) from None

    # ---- reading -----------------------------------------------------------------
    def runs(
        self,
        since: When = None,
        product: str | None = None,
        verdict: str | None = None,
        serial: str | None = None,
        until: When = None,
        lot: str | None = None,
        work_order: str | None = None,
    ) -> list[RunRow]:
        """Runs matching every filter given, oldest first."""
        query = (
            sa.select(runs)
            .where(*run_filters(since, until, product, verdict, serial, lot, work_order))
            .order_by(runs.c.started_utc, runs.c.run_id)
        )
        found = self._read(lambda con: con.execute(query).mappings().all())
        return [_run_row(r) for r in found]

    def folder_of(self, run_id: str) -> str | None:
        """Where the run's files are (its row's `folder`), or None when it is not indexed."""
        found = self._read(
            lambda con: con.scalar(sa.select(runs.c.folder).where(runs.c.run_id == run_id))
        )
        return None if found is None else str(found)

    def measurement_values(
        self,
        name: str | None = None,
        since: When = None,
        product: str | None = None,
        verdict: str | None = None,
        serial: str | None = None,
        until: When = None,
        lot: str | None = None,
        work_order: str | None = None,
    ) -> list[MeasurementRow]:
        """Measurements (of one name, or all) of the runs matching the filters, oldest first."""
        m, r = measurements.c, runs.c
        clauses = run_filters(since, until, product, verdict, serial, lot, work_order)
        if name is not None:
            clauses.append(m.name == name)
        query = (
            sa.select(m.run_id, r.serial, r.started_utc, r.verdict, m.name, m.condition,
                      m.value, m.units, m.low, m.high, m.outcome)
            .select_from(measurements.join(runs, r.run_id == m.run_id))
            .where(*clauses)
            .order_by(r.started_utc, m.run_id, m.seq)
        )
        return self._read(lambda con: [MeasurementRow(*row) for row in con.execute(query)])

    def calibration_elements(self, **filters: Any) -> list[CalibrationElement]:
        """The three-axis calibration elements of the runs matching the filters (as
        measurement_values takes them), oldest run first; none for single-axis runs."""
        e, r = calibration_elements.c, runs.c
        query = (
            sa.select(e.run_id, r.serial, e.quantity, e.axis, e.column_axis, e.value,
                      e.uncertainty_k2)
            .select_from(calibration_elements.join(runs, r.run_id == e.run_id))
            .where(*run_filters(**filters))
            .order_by(r.started_utc, e.run_id, e.seq)
        )
        return self._read(lambda con: [CalibrationElement(*row) for row in con.execute(query)])

    def measurement_names(self, **filters: Any) -> list[str]:
        """Distinct measurement names, in the order they first appear in the oldest run."""
        seen: dict[str, None] = {}
        for m in self.measurement_values(**filters):
            seen.setdefault(m.name, None)
        return list(seen)


def _run_row(r: Any) -> RunRow:
    return RunRow(
        run_id=r["run_id"], serial=r["serial"], product=r["product"],
        verdict=r["verdict"], reason=r["reason"],
        failed_measurements=tuple(json.loads(r["failed_measurements"] or "[]")),
        simulated=bool(r["simulated"]), started_utc=r["started_utc"],
        finished_utc=r["finished_utc"], station_id=r["station_id"],
        operator=r["operator"], software_version=r["software_version"],
        procedure_name=r["procedure_name"], procedure_sha256=r["procedure_sha256"],
        folder=r["folder"], calibration={k: r[f"cal_{k}"] for k in CAL_KEYS},
        work_order=r["work_order"], lot=r["lot"], attempt=r["attempt"],
        first_run_id=r["first_run_id"], axes=r["axes"], socket=r["socket"],
    )
