"""Retention: finished run folders older than some days packed into archives, then removed.

One archive per run folder (station/run_archive.py): the unit the manifest seals, so each
archive verifies on its own, one damaged file costs one run, and the database points at one
file per run. For each run folder due, in this order, so that a process killed at any point
loses nothing and a rerun completes what it began:

1. its folder verifies intact (an altered folder is left for a person to look at);
2. the archive is written as `.RUN.partial.tar.xz` (a leftover of an earlier attempt is
   removed first), fsynced, read back and verified against the folder's own manifest;
3. renamed to `RUN.tar.xz` and the folder holding it fsynced;
4. the results database's row points at `ARCHIVE#RUN`;
5. the run folder's files are removed, record.json last, then the folder.

A rerun finds `RUN.tar.xz` beside a folder that is still there: when it verifies and holds
the folder's manifest, steps 4 and 5 are done again; when it does not (cut short, damaged),
it is written again from the folder. A folder whose removal was cut short (files missing,
the rest as sealed) is removed once its archive verifies.
"""

from __future__ import annotations

import datetime as dt
import json
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from procedures.runtime.record import RECORD_FILE, Verdict, os_error_text, read_record
from station.manifest import MANIFEST_FILE, folder_changes, is_run_folder, verify_folder
from station.results_db import ResultsDB, ResultsDBError
from station.run_archive import SUFFIX, archive_ref, examine, write_archive
from station.run_folder import LOCK_FILE


class ArchiveFailed(Exception):
    """Archiving stopped; the message says what was kept and what to do."""


@dataclass
class Report:
    archived: list[Path] = field(default_factory=list)  # the archives written or completed
    young: int = 0  # finished fewer than DAYS ago
    running: int = 0  # a `.running` lock, or not finished
    skipped: list[str] = field(default_factory=list)  # one line each: why, what to do


def _finished(folder: Path) -> dt.datetime | None:
    record = read_record(folder)
    if record.verdict is Verdict.RUNNING or not record.finished_utc:
        return None
    t = dt.datetime.fromisoformat(record.finished_utc.replace("Z", "+00:00"))
    return t if t.tzinfo else t.replace(tzinfo=dt.UTC)


def due_folders(root: Path, out: Path, days: float, now: dt.datetime,
                report: Report) -> list[Path]:
    """The run folders under root (one level) finished at least `days` ago, not running;
    and empty folders left by an interrupted removal whose archive is in `out`."""
    due = []
    for folder in sorted(p for p in root.iterdir() if p.is_dir() and p.resolve() != out):
        if not any(folder.iterdir()) and (out / f"{folder.name}{SUFFIX}").is_file():
            due.append(folder)
            continue
        if not is_run_folder(folder):
            continue
        if (folder / LOCK_FILE).exists():
            report.running += 1
            continue
        try:
            finished = _finished(folder)
        except ValueError as exc:
            report.skipped.append(f"{folder}: record not readable ({exc}); not archived")
            continue
        if finished is None:
            report.running += 1
        elif now - finished < dt.timedelta(days=days):
            report.young += 1
        else:
            due.append(folder)
    return due


def _fsync_dir(folder: Path) -> None:
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _manifest(folder: Path) -> bytes:
    try:
        return (folder / MANIFEST_FILE).read_bytes()
    except OSError:
        return b""


def _archive_holds(target: Path, folder: Path, trusted: set[str] | None) -> bool:
    """The archive verifies and holds this folder's manifest, and the folder is either
    intact or what an interrupted removal left (files removed, none changed)."""
    if not target.is_file():
        return False
    result, manifest = examine(target, trusted)
    if not result.intact:
        return False
    if not any(folder.iterdir()):
        return True
    here = _manifest(folder)
    if here and here != manifest:
        return False
    changes = folder_changes(folder, _sealed_files(manifest))
    return all(state == "removed" for state in changes.values())


def _sealed_files(manifest: bytes) -> dict[str, Any]:
    files = json.loads(manifest)["body"]["files"]
    return files if isinstance(files, dict) else {}


def _write(folder: Path, target: Path, trusted: set[str] | None) -> None:
    """Steps 1-3 (the module's docstring)."""
    check = verify_folder(folder, trusted)
    if not check.intact:
        raise ValueError(f"{folder} failed verification ({'; '.join(check.problems)}); "
                         f"not archived: look at it with `station verify {folder}`")
    partial = target.with_name(f".{folder.name}.partial{SUFFIX}")
    partial.unlink(missing_ok=True)
    try:
        write_archive(folder, partial)
    except OSError as exc:
        partial.unlink(missing_ok=True)
        raise ArchiveFailed(
            f"cannot write {target} ({exc.strerror or exc}); archive left out, {folder} kept: "
            f"free space in {target.parent} or give --out FOLDER on another disk") from None
    result, manifest = examine(partial, trusted)
    if not result.intact or manifest != _manifest(folder):
        partial.unlink(missing_ok=True)
        raise ArchiveFailed(f"{target} did not verify after writing ({'; '.join(result.problems)}"
                            f"); archive left out, {folder} kept: check the disk of "
                            f"{target.parent}")
    os.replace(partial, target)
    _fsync_dir(target.parent)


def _remove(folder: Path) -> None:
    """Step 5: every file, record.json last (a folder cut short stays a run folder)."""
    for entry in sorted(folder.iterdir(), key=lambda p: p.name == RECORD_FILE):
        entry.unlink()
    folder.rmdir()
    _fsync_dir(folder.parent)


def _point_at(db: ResultsDB, folder: Path, target: Path) -> None:
    """Step 4 (a run not indexed yet is indexed from its record first)."""
    run_id = read_record(folder).run_id
    if db.folder_of(run_id) is None:
        db.add_run(folder)
    db.relocate(run_id, archive_ref(target.resolve(), folder.name))


def archive_folder(folder: Path, out: Path, db: ResultsDB | None,
                   trusted: set[str] | None) -> Path:
    """Archive one run folder (steps 1-5); returns the archive. ValueError: this folder is
    not archived (the message says why); ArchiveFailed: stop archiving."""
    target = out / f"{folder.name}{SUFFIX}"
    if not _archive_holds(target, folder, trusted):
        _write(folder, target, trusted)
    if db is not None and (folder / RECORD_FILE).is_file():
        try:
            _point_at(db, folder, target)
        except ResultsDBError as exc:
            raise ArchiveFailed(f"{exc}; {target} is written and {folder} kept: run the same "
                                "`station archive` again once the database answers") from None
    _remove(folder)
    return target


def archive_runs(root: Path, out: Path, days: float, db: ResultsDB | None,
                 trusted: set[str] | None, now: dt.datetime | None = None,
                 progress: Callable[[Path, Path], None] | None = None) -> Report:
    """Archive every run folder under root that is due (due_folders) into `out`."""
    out.mkdir(parents=True, exist_ok=True)
    report = Report()
    moment = now or dt.datetime.now(dt.UTC)
    for folder in due_folders(root, out.resolve(), days, moment, report):
        try:
            target = archive_folder(folder, out, db, trusted)
        except ValueError as exc:
            report.skipped.append(str(exc))
            continue
        except OSError as exc:  # renaming, removing: the steps' order keeps the data
            raise ArchiveFailed(
                f"{folder}: {os_error_text(exc)}; stopped, nothing lost (the folder stays "
                "until its archive is written and verified): fix that and run the same "
                "`station archive` again") from None
        report.archived.append(target)
        if progress is not None:
            progress(folder, target)
    return report
