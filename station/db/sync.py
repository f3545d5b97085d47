"""Store-and-forward: a station's runs, written to its local database first, pushed to the
line's central database by a sync thread (and by `station sync` once).

Runs go in batches (Sync.BATCH runs with their measurements and calibration elements per
central transaction; what is queued goes at once, one run or many). Each run is upserted by
run_id (rows inserted with ON CONFLICT DO NOTHING after any older copy is deleted), so a run
delivered twice (the station died between the central commit and marking it sent, or a
batch was interrupted and retried) is still there once. A run re-indexed locally (crash
recovery marking it ERROR) is queued again with a higher version and delivered again. While
the central database is unreachable the sync retries with exponential backoff; the station
keeps testing, since it only ever writes locally.
"""

from __future__ import annotations

import atexit
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import sqlalchemy as sa
from sqlalchemy.exc import SQLAlchemyError

from station import __version__
from station.db.connect import DatabaseError, database_url, engine_for, shown
from station.db.schema import calibration_elements, measurements, outbox, runs, stations
from station.db.store import replace_runs, utc_now

log = logging.getLogger(__name__)

Rows = list[dict[str, Any]]


class SyncError(DatabaseError):
    """The central database could not be reached or written; the runs stay queued locally."""


@dataclass(frozen=True)
class SyncReport:
    sent: int  # runs delivered by this call
    pending: int  # runs still queued after it


class Sync:
    """Pushes one local database's queued runs to one central database, `batch` runs (with
    their measurements and calibration elements) per central transaction. Whatever is
    queued goes at once: a single run just ended is sent alone, never held for a batch."""

    BATCH = 1000

    def __init__(self, local: str, central: str, station_id: str = "",
                 software_version: str = "", batch: int = BATCH) -> None:
        self.local_url = database_url(local)
        self.central_url = database_url(central)
        if self.local_url == self.central_url:
            raise SyncError(f"central_db is the station's own results_db "
                            f"({shown(self.local_url)}); give the line's database")
        self.station_id = station_id
        self.software_version = software_version
        self.batch = batch
        self.state: Callable[[], str] = lambda: "idle"
        self._push_lock = threading.Lock()

    def pending(self) -> int:
        local = engine_for(self.local_url)
        with local.connect() as con:
            return int(con.scalar(
                sa.select(sa.func.count()).select_from(outbox)
                .where(outbox.c.sent_version < outbox.c.version)
            ) or 0)

    def push_once(self) -> SyncReport:
        """Deliver every queued run (in batches); raise SyncError when the central database
        cannot be reached (what was delivered before stays delivered)."""
        sent = 0
        with self._push_lock:
            while True:
                n = self._push_batch()
                sent += n
                if n < self.batch:
                    break
            pending = self.pending()
            self._heartbeat(pending)
        return SyncReport(sent=sent, pending=pending)

    def _push_batch(self) -> int:
        """One batch: read up to `batch` queued runs locally, write them centrally in one
        transaction, then mark them sent locally. Interrupted anywhere, it is safe to run
        again: the central transaction is all or nothing, and a batch delivered but not
        marked is delivered again as a replacement of itself (one copy of each run)."""
        local = engine_for(self.local_url)
        with local.connect() as con:
            queued = self._queued(con)
            if not queued:
                return 0
            rows, meas, elements = _read_runs(con, list(queued))
        try:
            with engine_for(self.central_url).begin() as con:
                replace_runs(con, rows, meas, queue=False, elements=elements)
        except (SQLAlchemyError, DatabaseError) as exc:
            raise SyncError(
                f"central database {shown(self.central_url)} not reachable "
                f"({str(exc).splitlines()[0]}); {len(queued)}+ runs stay queued locally"
            ) from None
        self._mark_sent(queued)
        return len(queued)

    def _queued(self, con: sa.Connection) -> dict[str, int]:
        """run_id -> version of the oldest `batch` runs not yet delivered at their version."""
        return {
            r.run_id: r.version
            for r in con.execute(
                sa.select(outbox.c.run_id, outbox.c.version)
                .where(outbox.c.sent_version < outbox.c.version)
                .order_by(outbox.c.queued_utc, outbox.c.run_id)
                .limit(self.batch)
            )
        }

    def _mark_sent(self, queued: dict[str, int]) -> None:
        now = utc_now()  # a queued run since deleted locally counts as delivered too
        with engine_for(self.local_url).begin() as con:
            con.execute(
                outbox.update()
                .where(outbox.c.run_id == sa.bindparam("rid"))
                .values(sent_version=sa.bindparam("v"), sent_utc=now),
                [{"rid": rid, "v": v} for rid, v in queued.items()],
            )

    def _heartbeat(self, pending: int) -> None:
        if not self.station_id:
            return
        row: dict[str, Any] = {
            "station_id": self.station_id, "last_seen_utc": utc_now(), "state": self.state(),
            "pending_runs": pending, "software_version": self.software_version,
        }
        try:
            with engine_for(self.central_url).begin() as con:
                con.execute(stations.delete().where(stations.c.station_id == self.station_id))
                con.execute(stations.insert(), [row])
        except (SQLAlchemyError, DatabaseError) as exc:
            raise SyncError(f"central database {shown(self.central_url)}: heartbeat not "
                            f"written ({str(exc).splitlines()[0]})") from None


def _read_runs(con: sa.Connection, ids: list[str]) -> tuple[Rows, Rows, Rows]:
    """The runs, measurements and calibration elements of these runs, as rows."""
    return (_rows_of(con, runs, ids), _rows_of(con, measurements, ids),
            _rows_of(con, calibration_elements, ids))


def _rows_of(con: sa.Connection, table: sa.Table, ids: list[str]) -> Rows:
    query = sa.select(table).where(table.c.run_id.in_(ids))
    return [dict(r) for r in con.execute(query).mappings()]


class SyncThread:
    """Runs Sync.push_once every interval, at once when woken, with backoff during outages."""

    def __init__(self, sync: Sync, interval_s: float = 5.0, max_backoff_s: float = 60.0) -> None:
        self.sync = sync
        self.interval_s = interval_s
        self.max_backoff_s = max_backoff_s
        self.last_error = ""
        self.failures = 0
        self._wake = threading.Event()
        self._force = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="results-sync", daemon=True)

    def start(self) -> SyncThread:
        self._thread.start()
        return self

    def wake(self, force: bool = False) -> None:
        """A run was just written locally: push it now rather than at the next interval.
        During an outage the backoff holds (each run ending does not hammer the server)
        unless force (someone knows the central database is back)."""
        self._force = self._force or force
        self._wake.set()

    def stop(self, flush_timeout_s: float = 5.0) -> None:
        """Stop the thread after one last attempt to deliver (bounded by the timeout)."""
        self._stop.set()
        self._wake.set()
        self._thread.join(flush_timeout_s)

    def delay_s(self) -> float:
        if self.failures == 0:
            return self.interval_s
        return float(min(self.max_backoff_s, self.interval_s * 2 ** min(self.failures, 16)))

    def _pause(self) -> None:
        """Wait the interval (or the backoff); a wake ends it early unless backing off."""
        deadline = time.monotonic() + self.delay_s()
        while not self._stop.is_set():
            remaining = deadline - time.monotonic()
            if remaining <= 0 or not self._wake.wait(remaining):
                return
            self._wake.clear()
            if self.failures == 0 or self._force:
                return

    def _loop(self) -> None:
        while True:
            self._wake.clear()
            self._force = False
            try:
                self.sync.push_once()
                if self.failures:
                    log.warning("central database reachable again after %d failed attempts",
                                self.failures)
                self.failures, self.last_error = 0, ""
            except (SyncError, DatabaseError, SQLAlchemyError) as exc:
                self.failures += 1
                self.last_error = str(exc)
                log.warning("sync: %s; retrying in %.0f s", exc, self.delay_s())
            if self._stop.is_set():
                return
            self._pause()


_threads: dict[tuple[str, str], SyncThread] = {}
_threads_lock = threading.Lock()


def station_sync(local: str, central: str, *, station_id: str, software_version: str = "",
                 interval_s: float = 5.0) -> SyncThread:
    """The process's sync thread for this local/central pair (started on first use, and given
    a last chance to deliver when the process exits)."""
    key = (database_url(local), database_url(central))
    with _threads_lock:
        thread = _threads.get(key)
        if thread is None:
            sync = Sync(local, central, station_id=station_id, software_version=software_version)
            thread = SyncThread(sync, interval_s=interval_s).start()
            _threads[key] = thread
            atexit.register(thread.stop)
    return thread


def stop_all() -> None:
    with _threads_lock:
        for t in _threads.values():
            t.stop()
        _threads.clear()


def wait_delivered(sync: Sync, timeout_s: float, poll_s: float = 0.05) -> bool:
    """True once nothing is queued (for tests and `station sync --wait`)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if sync.pending() == 0:
            return True
        time.sleep(poll_s)
    return sync.pending() == 0


def wake_station_sync(settings: Any, local: str, force: bool = False,
                      state: Callable[[], str] | None = None) -> None:
    """After a run is written locally: start (once) and wake the station's sync thread, when
    station.yaml names a central database (settings: station.settings.LoadedSettings).
    force: try now even while backing off from an outage (a station starting).
    state: what the station is doing, for the line's dashboard (sent with each sync)."""
    central = settings.central_db
    if not central:
        return

    thread = station_sync(
        local, central, station_id=settings.settings.station.id, software_version=__version__,
        interval_s=settings.settings.sync_interval_s,
    )
    if state is not None:
        thread.sync.state = state
    thread.wake(force)


def store_finished_run(db: Any, settings: Any, folder: Any, record: Any,
                       state: Callable[[], str] | None = None) -> None:
    """What the station does when a run ends (UutRunner): index it in the local results
    database (db: station.results_db.ResultsDB), then wake the sync to the central one."""
    db.add_run(folder, record)
    wake_station_sync(settings, db.url, state=state)
