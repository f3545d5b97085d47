"""Run history for the review screen: the run folders under the station's output directory.

Each run folder holds its record.json (procedures/runtime/record.py), so the history is read from
there; records are cached by modification time, so a refresh only reads new or changed runs.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import logging
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from procedures.runtime.record import CERTIFICATE_FILE, RECORD_FILE, RunRecord, read_record
from station.errors import UserError
from station.run_folder import recover_results

log = logging.getLogger(__name__)

_KEY_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.:+\-]{0,160}$")


def result_from_record(record: RunRecord, folder: Path) -> dict[str, Any]:
    """The UI's view of one part's finished run (what the verdict panel and review show)."""
    failed = [
        {
            "name": m.name,
            "value": m.value,
            "units": m.units,
            "low": m.low,
            "high": m.high,
            "condition": m.condition,
        }
        for m in record.measurements
        if m.outcome == "FAIL"
    ]
    return {
        "socket": record.dut.socket,
        "serial": record.dut.serial,
        "verdict": str(record.verdict),
        "reason": record.reason,
        "failed": failed,
        # passed, but inside a marginal band: the card says how many, in plain words
        "marginal": sum(1 for m in record.measurements if m.outcome == "MARGINAL"),
        "run_folder": str(folder),
    }


@dataclass(frozen=True)
class RunFilter:
    serial: str = ""  # substring, case-insensitive
    verdict: str = ""  # PASS | FAIL | ERROR | ABORTED, empty for all
    product: str = ""  # substring of the product name
    operator: str = ""
    since: str = ""  # ISO date or date-time, inclusive
    until: str = ""  # ISO date or date-time, inclusive (a bare date covers the whole day)

    def matches(self, row: dict[str, Any]) -> bool:
        if self.serial and self.serial.lower() not in row["serial"].lower():
            return False
        if self.verdict and row["verdict"] != self.verdict.upper():
            return False
        if self.product and self.product.lower() not in row["product"].lower():
            return False
        if self.operator and self.operator.lower() not in row["operator"].lower():
            return False
        started = row["started_utc"]
        if self.since and started < self.since:
            return False
        return not (self.until and started[: len(self.until)] > self.until)


class History:
    """The runs under `out_dir`; through the results database when there is one (an index
    that stays fast over months of runs), else by reading every run folder's record."""

    RECOVER_EVERY_S = 2.0  # a crashed station's run is looked for at most this often

    def __init__(
        self, out_dir: Path, db_path: Path | str | None = None,
        seal: Callable[[Path], None] | None = None,
    ) -> None:
        self.out_dir = out_dir
        self.db_path = db_path
        self.seal = seal  # numbers and seals a recovered run (UutRunner.seal_recovered)
        self._lock = threading.Lock()
        self._cache: dict[Path, tuple[float, dict[str, Any] | None]] = {}
        self._recovered_at = -1e9

    def recover(self, *, locks_only: bool = False) -> list[Path]:
        """Mark ERROR (and index) the runs of a station that died mid-run: they show here
        as ERROR with the last step they completed, not as missing or RUNNING."""
        self._recovered_at = time.monotonic()
        return recover_results(self.out_dir, self.db_path, locks_only=locks_only, seal=self.seal)

    def query(
        self, flt: RunFilter, limit: int = 500
    ) -> tuple[dict[str, Any], list[dict[str, Any]]]:
        """(yield summary over every match, the newest `limit` matches) for the review."""
        rows = self.rows(flt)
        page = rows[:limit]
        for row in page:
            if "certificate_url" not in row:
                folder = self.folder(row["key"])
                has_pdf = folder is not None and (folder / CERTIFICATE_FILE).is_file()
                row["certificate_url"] = f"/runs/{row['key']}/certificate.pdf" if has_pdf else None
        return yield_summary(rows), page

    def rows(self, flt: RunFilter | None = None) -> list[dict[str, Any]]:
        """Every run, newest first, as flat rows for the review table."""
        flt = flt or RunFilter()
        if time.monotonic() - self._recovered_at > self.RECOVER_EVERY_S:
            self.recover(locks_only=True)
        source = self._db_rows(flt) if self._use_db() else self._scan()
        rows = [r for r in source if flt.matches(r)]
        rows.sort(key=lambda r: r["started_utc"], reverse=True)
        return rows

    def _use_db(self) -> bool:
        if isinstance(self.db_path, str):  # a database server's URL
            return True
        return self.db_path is not None and self.db_path.is_file()

    def _db_rows(self, flt: RunFilter) -> list[dict[str, Any]]:
        # sqlalchemy: loaded only when a database is used
        from station.results_db import ResultsDB, ResultsDBError

        until = flt.until or None
        if until and len(until) == 10:  # a bare date: the whole day (the database's is exclusive)
            with contextlib.suppress(ValueError):
                until = (dt.date.fromisoformat(until) + dt.timedelta(days=1)).isoformat()
        try:
            found = ResultsDB(self.db_path).runs(  # type: ignore[arg-type]
                since=flt.since or None, until=until, verdict=flt.verdict or None
            )
        except ResultsDBError as exc:
            raise UserError(str(exc)) from None
        return [
            {
                "key": Path(r.folder).name,
                "run_id": r.run_id,
                "socket": r.socket or "",  # 0: indexed before sockets were (schema < 5)
                "serial": r.serial,
                "verdict": r.verdict,
                "reason": r.reason,
                "failed": [{"name": n} for n in r.failed_measurements],
                "started_utc": r.started_utc,
                "finished_utc": r.finished_utc or "",
                "operator": r.operator,
                "product": r.product,
                "procedure": r.procedure_name,
                "simulated": r.simulated,
            }
            for r in found
        ]

    def folder(self, key: str) -> Path | None:
        """The run folder named `key`, only if it is one of this station's runs."""
        if not _KEY_RE.match(key):
            return None
        candidate = self.out_dir / key
        if (candidate / RECORD_FILE).is_file():
            return candidate
        return None

    def _scan(self) -> list[dict[str, Any]]:
        if not self.out_dir.is_dir():
            return []
        rows = []
        with self._lock:
            seen = set()
            for record_path in self.out_dir.glob(f"*/{RECORD_FILE}"):
                folder = record_path.parent
                seen.add(folder)
                try:
                    mtime = record_path.stat().st_mtime
                except OSError:
                    continue
                cached = self._cache.get(folder)
                if cached is None or cached[0] != mtime:
                    cached = (mtime, self._row(folder))
                    self._cache[folder] = cached
                if cached[1] is not None:
                    rows.append(cached[1])
            for gone in set(self._cache) - seen:
                del self._cache[gone]
        return rows

    def _row(self, folder: Path) -> dict[str, Any] | None:
        try:
            record = read_record(folder)
        except ValueError as exc:
            log.warning("review skips a run folder: %s", exc)
            return None
        row = result_from_record(record, folder)
        del row["run_folder"]
        row.update(
            key=folder.name,
            run_id=record.run_id,
            started_utc=record.started_utc,
            finished_utc=record.finished_utc or "",
            operator=record.operator,
            product=record.product.name or Path(record.product.path).stem,
            procedure=record.procedure.name or Path(record.procedure.path).stem,
            simulated=record.simulated,
            certificate_url=(
                f"/runs/{folder.name}/certificate.pdf"
                if (folder / CERTIFICATE_FILE).is_file()
                else None
            ),
        )
        return row


def yield_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Counts per verdict and the yield: PASS over parts that completed (PASS + FAIL)."""
    counts = {v: 0 for v in ("PASS", "FAIL", "ERROR", "ABORTED")}
    for row in rows:
        if row["verdict"] in counts:
            counts[row["verdict"]] += 1
    completed = counts["PASS"] + counts["FAIL"]
    return {
        "counts": counts,
        "total": len(rows),
        "completed": completed,
        "yield": counts["PASS"] / completed if completed else None,
    }
