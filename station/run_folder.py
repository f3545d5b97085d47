"""Run folders: `<out>/<UTC time>_<serial>/`, serial checks, and crash recovery.

A scanned serial becomes part of a path, so it is checked twice: against the product's
pattern, and against a fixed safe alphabet so that nothing like `../../x` can ever leave
the output folder. A running run holds a `.running` lock file with its process id; a run
whose record still says RUNNING but whose process is gone crashed, and `recover_crashed_runs`
marks it ERROR (its data stay where they are).
"""

from __future__ import annotations

import datetime as dt
import json
import logging
import os
import re
import socket
import tempfile
from collections.abc import Callable
from pathlib import Path

from procedures.runtime.record import (
    RECORD_FILE,
    Event,
    RunRecord,
    Verdict,
    read_record,
    write_record,
)
from station.errors import UserError

log = logging.getLogger(__name__)

LOCK_FILE = ".running"
_SAFE_SERIAL = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")


def validate_serial(serial: str, pattern: str | None = None) -> str:
    """Return the serial if it is safe as a folder name and matches `pattern`; UserError if not."""
    s = serial.strip()
    if not _SAFE_SERIAL.match(s) or ".." in s:
        raise UserError(
            f"serial {serial!r} is not allowed: use 1-64 letters, digits, '.', '_' or '-', "
            "starting with a letter or digit (no path separators); rescan the label"
        )
    if pattern is not None and not re.fullmatch(pattern, s):
        raise UserError(
            f"serial {s!r} does not match the product's serial pattern {pattern!r}; "
            "rescan the label or choose the right product file"
        )
    return s


def utc_stamp(now: dt.datetime | None = None) -> str:
    now = now or dt.datetime.now(dt.UTC)
    return now.astimezone(dt.UTC).strftime("%Y%m%dT%H%M%SZ")


def create_run_folder(out: Path, serial: str, now: dt.datetime | None = None) -> Path:
    """Make a new, empty `<out>/<UTC time>_<serial>/` (suffixed if it exists) and lock it."""
    validate_serial(serial)
    root = Path(out).expanduser().resolve()
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # e.g. a file of that name: a traceback would read as FAIL
        raise UserError(
            f"cannot use {out} as the output folder ({exc.strerror}); choose another --out"
        ) from None
    base = f"{utc_stamp(now)}_{serial}"
    for n in range(1, 1000):
        folder = root / (base if n == 1 else f"{base}-{n}")
        if not folder.resolve().is_relative_to(root):  # belt and braces: never outside out
            raise UserError(f"serial {serial!r} would leave the output folder; rescan the label")
        try:
            folder.mkdir()
        except FileExistsError:
            continue
        (folder / LOCK_FILE).write_text(
            json.dumps({"pid": os.getpid(), "host": socket.gethostname()}), encoding="utf-8"
        )
        return folder
    raise UserError(f"too many run folders named {base} in {root}; clean up the output folder")


def release(folder: Path) -> None:
    """The run has finished (any verdict): drop its lock (a folder gone read-only keeps it,
    said in the log; the next start's recovery finds the run finished)."""
    try:
        (folder / LOCK_FILE).unlink(missing_ok=True)
    except OSError as exc:
        log.error("cannot remove the lock %s: %s", folder / LOCK_FILE, exc.strerror or exc)


def check_output_folder(out: Path, min_free_mb: float) -> None:
    """Before a run: the output folder (or the folder it will be made in) can be written and
    has at least `min_free_mb` MB free (station.yaml min_free_space_mb); UserError in one
    line if not."""
    where = f"the output folder {out}"
    # nothing is made here: a folder not there yet is judged by the folder it would go in
    existing = next((p for p in (out, *out.parents) if p.exists()), Path("/"))
    if not existing.is_dir():
        raise UserError(f"{where} cannot be made: {existing} is a file; choose another --out")
    try:
        with tempfile.TemporaryFile(dir=existing, prefix=".write-check-"):
            pass
        st = os.statvfs(existing)
    except OSError as exc:
        raise UserError(
            f"{where} cannot be written ({exc.strerror or exc}); choose another --out or "
            "fix the disk"
        ) from None
    free_mb = st.f_bavail * st.f_frsize / 1e6
    if free_mb < min_free_mb:
        raise UserError(
            f"{where} has {free_mb:.1f} MB free, less than the {min_free_mb:g} MB a run needs "
            "(station.yaml min_free_space_mb); free space or choose another --out"
        )


def _process_alive(lock: Path) -> bool:
    try:
        with lock.open("rb") as fh:  # a lock is one short line; read no more than a page
            info = json.loads(fh.read(4096).decode("utf-8"))
        if not isinstance(info, dict):
            return False
    except (OSError, ValueError):
        return False
    if info.get("host") != socket.gethostname():
        return True  # cannot tell from here; leave it alone
    pid = int(info.get("pid", 0))
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def last_completed_step(record: RunRecord) -> str:
    """The last step the run finished before it stopped, '' when none had.

    The engine adds a step's time to `timings` when the step ends (in the order the steps
    ran, "total" only at the very end), so the last key is the last completed step; the
    events' last step is the one that was still running, which is not the one to name."""
    done = [k for k in record.timings if k != "total"]
    return done[-1] if done else ""


def _crash_reason(record: RunRecord) -> str:
    last = last_completed_step(record)
    running = record.events[-1].step if record.events else ""
    where = f"after step {last!r} completed" if last else "before any step completed"
    if running and running != last and running not in ("recovery", "finish"):
        where += f" (last event from {running!r})"
    return (
        "the station stopped during the run (crash, kill or power loss) "
        + where
        + "; everything measured up to then is kept in this folder; rerun the part"
    )


def _candidates(root: Path, locks_only: bool) -> list[Path]:
    if locks_only:  # cheap: a run that was RUNNING when its station died still has its lock
        return sorted(lock.parent for lock in root.glob(f"*/{LOCK_FILE}"))
    return sorted(record_path.parent for record_path in root.glob(f"*/{RECORD_FILE}"))


def recover_crashed_runs(
    out: Path, *, locks_only: bool = False, seal: Callable[[Path], None] | None = None
) -> list[Path]:
    """Mark ERROR every run under `out` left RUNNING by a process that no longer exists,
    naming the last step it completed. `locks_only` looks only at folders still holding a
    `.running` lock (cheap enough for every refresh of the review screen). `seal(folder)`
    then numbers and seals each recovered folder as a finished run's is (station/certify.py);
    a failure there is logged and the folder stays recovered, unsealed."""
    root = Path(out)
    if not root.is_dir():
        return []
    recovered: list[Path] = []
    for folder in _candidates(root, locks_only):
        if not (folder / RECORD_FILE).is_file():
            continue
        try:
            record = read_record(folder)
        except (ValueError, OSError) as exc:
            log.warning("skipping unreadable run folder %s: %s", folder, exc)
            continue
        if record.verdict is not Verdict.RUNNING:
            continue
        lock = folder / LOCK_FILE
        if lock.exists() and _process_alive(lock):
            continue
        now = dt.datetime.now(dt.UTC).isoformat()
        record.verdict = Verdict.ERROR
        record.reason = _crash_reason(record)
        record.finished_utc = record.finished_utc or now
        record.events.append(
            Event(
                time_utc=now,
                station_time_s=0.0,
                level="ERROR",
                step="recovery",
                message=record.reason,
            )
        )
        try:
            write_record(folder, record)
            lock.unlink(missing_ok=True)
        except OSError as exc:
            log.error("could not mark crashed run %s as ERROR: %s", folder, exc)
            continue
        if seal is not None:
            _seal_recovered(folder, seal)
        recovered.append(folder)
        log.warning("marked crashed run %s as ERROR", folder)
    return recovered


def _seal_recovered(folder: Path, seal: Callable[[Path], None]) -> None:
    try:
        seal(folder)
    except Exception as exc:  # the record stands; `station verify` will say it is unsealed
        log.error("recovered run %s could not be sealed: %s", folder, exc)


def recover_results(
    out: Path, db_path: Path | str | None, *, locks_only: bool = False,
    seal: Callable[[Path], None] | None = None,
) -> list[Path]:
    """Recovery for an entry point that opens the results: crashed runs marked ERROR (and
    sealed, with `seal`) and indexed in the results database (when there is one), so that
    history and review list them."""
    folders = recover_crashed_runs(out, locks_only=locks_only, seal=seal)
    if folders and db_path is not None:
        try:
            from station.results_db import ResultsDB

            db = ResultsDB(db_path)
            for folder in folders:
                db.add_run(folder, read_record(folder))
        except Exception as exc:  # the run folders are the master copy; the index can be rebuilt
            log.error("results database: could not record crashed runs: %s", exc)
    return folders
