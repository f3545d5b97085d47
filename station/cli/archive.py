"""`station archive`: finished run folders older than DAYS packed into archives (retention).

    station archive --older-than DAYS [--out FOLDER] [--db PATH] [--station FILE] [RUNS_DIR]
        RUNS_DIR: station.yaml's output_folder by default; FOLDER: RUNS_DIR/archive
        exit 0 every run due archived, 1 some left (each named, with what to do), 2 bad input
        or archiving stopped (disk full, database down: what was kept, what to do)

One RUN.tar.xz per run folder (station/run_archive.py); the order of the steps and how a
rerun completes an interrupted one: station/retention.py. `station verify RUN.tar.xz` checks
an archive as it checks a folder.
"""

from __future__ import annotations

import argparse
import fcntl
import math
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from station.cli.signing import station_settings, trusted_for
from station.errors import UserError
from station.results_db import ResultsDB, ResultsDBError
from station.retention import ArchiveFailed, archive_runs
from station.settings import LoadedSettings


def parse_days(text: str) -> float:
    try:
        days = float(text)
    except ValueError:
        days = math.nan
    if not math.isfinite(days) or days <= 0:
        raise UserError(f"--older-than {text!r}: give a positive number of days, e.g. "
                        "--older-than 90")
    return days


def _places(args: argparse.Namespace) -> tuple[Path, Path | str | None]:
    """The runs folder and the results database (None: none to update)."""
    settings = station_settings(args.station)
    loaded = settings if isinstance(settings, LoadedSettings) else None
    if args.runs_dir:
        root = Path(args.runs_dir)
    elif loaded is not None:
        root = loaded.output_folder
    else:
        raise UserError("no runs folder: give the folder holding the run folders "
                        "(station.yaml's output_folder) as the last argument")
    if not root.is_dir():
        raise UserError(f"{root}: no such folder; give the folder holding the run folders "
                        "(station.yaml's output_folder)")
    db: Path | str | None = args.db or (loaded.results_db if loaded is not None else None)
    if isinstance(db, str) and "://" not in db:
        db = Path(db)
    if isinstance(db, Path) and not db.exists():
        raise UserError(f"results database {db} does not exist; give the station's with "
                        "--db PATH (the archived runs' rows must point at their archives)")
    return root, db


@contextmanager
def _one_at_a_time(out: Path) -> Iterator[None]:
    """Only one `station archive` writes into a folder at a time."""
    fd = os.open(out / ".archive.lock", os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise UserError(f"another `station archive` is writing into {out}; wait for it to "
                            "finish and run this one again") from None
        yield
    finally:
        os.close(fd)


def _out_folder(args: argparse.Namespace, root: Path) -> Path:
    out = Path(args.out) if args.out else root / "archive"
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out} is a file; give a folder for the archives")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"--out {out}: cannot create it ({exc.strerror or exc}); give a "
                        "folder this user can write") from None
    return out


def cmd_archive(args: argparse.Namespace) -> int:
    days = parse_days(args.older_than)
    root, db_path = _places(args)
    out = _out_folder(args, root)
    trusted, _ = trusted_for(args)
    try:
        db = ResultsDB(db_path) if db_path is not None else None
    except ResultsDBError as exc:
        raise UserError(str(exc)) from None
    with _one_at_a_time(out):
        try:
            report = archive_runs(root, out, days, db, trusted,
                                  progress=lambda f, a: print(f"archived {f} -> {a}"))
        except ArchiveFailed as exc:
            raise UserError(str(exc)) from None
    for line in report.skipped:
        print(f"not archived: {line}", file=sys.stderr)
    print(f"{len(report.archived)} archived into {out}; {report.young} younger than "
          f"{args.older_than} days, {report.running} running or unfinished, "
          f"{len(report.skipped)} left to look at" + ("" if db else "; no results database "
                                                      "updated"))
    return 1 if report.skipped else 0


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "archive", help="pack finished run folders older than DAYS into archives")
    p.add_argument("runs_dir", metavar="RUNS_DIR", nargs="?",
                   help="the folder holding the run folders (default: station.yaml's "
                        "output_folder)")
    p.add_argument("--older-than", metavar="DAYS", required=True,
                   help="archive runs that finished at least DAYS days ago")
    p.add_argument("--out", metavar="FOLDER",
                   help="where the archives go (default: RUNS_DIR/archive)")
    p.add_argument("--db", metavar="PATH",
                   help="results database whose rows to point at the archives "
                        "(default: station.yaml's)")
    p.add_argument("--station", metavar="FILE", help="station file (default: config/station.yaml)")
    p.set_defaults(handler=cmd_archive, trust=None)
