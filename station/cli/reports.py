"""`station report`, `station history`, `station lot-report`: the quality engineer's review.

    station report RUN_FOLDER [--index] [--db PATH] [--unverified] [--station FILE]
    station history [--since DATE] [--until DATE] [--product P] [--verdict V] [--serial S]
                    [--lot LOT] [--work-order WO] [--db PATH] [--json] [--reindex RUNS_DIR]
    station lot-report [same filters] --out FILE.pdf [--issued TIME] [--include-simulated]
                       [--db PATH]

The database defaults to the one named in config/station.yaml (`results_db`), or
runs/results.sqlite when no station file can be loaded.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import Any

from procedures.runtime.record import CERTIFICATE_FILE, RAW_DATA_FILE, RECORD_FILE, read_record
from reports.lot_rows import RunRow
from station.errors import UserError
from station.manifest import MANIFEST_FILE, verify_folder
from station.results_db import ResultsDB, ResultsDBError
from station.run_folder import recover_results
from station.settings import LoadedSettings
from station.station_file import load_settings

log = logging.getLogger(__name__)

FALLBACK_DB = Path("runs/results.sqlite")
UNVERIFIED_FILE = "certificate-UNVERIFIED.pdf"
VERDICTS = ("PASS", "FAIL", "ERROR", "ABORTED", "RUNNING")


def plural(n: int, noun: str) -> str:
    """'1 run', '2 runs'."""
    return f"{n} {noun}{'' if n == 1 else 's'}"


def default_db_path() -> Path | str:
    """The station file's results database, or runs/results.sqlite without one."""
    try:
        return load_settings().results_db
    except Exception as exc:  # no station.yaml, or settings not part of this build
        log.info("station settings not loaded (%s); using %s", exc, FALLBACK_DB)
        return FALLBACK_DB


def _open_db(args: argparse.Namespace, must_exist: bool) -> ResultsDB:
    path: Path | str = (
        (args.db if "://" in args.db else Path(args.db)) if args.db else default_db_path()
    )
    if must_exist and isinstance(path, Path) and not path.exists():
        raise UserError(
            f"results database {path} does not exist; give the right one with --db PATH "
            "(runs are indexed there by `station run`)"
        )
    try:
        return ResultsDB(path)
    except ResultsDBError as exc:
        raise UserError(str(exc)) from exc


def _filters(args: argparse.Namespace) -> dict[str, Any]:
    return {
        "since": args.since,
        "until": args.until,
        "product": args.product,
        "verdict": args.verdict.upper() if args.verdict else None,
        "serial": args.serial,
        "lot": args.lot,
        "work_order": args.work_order,
    }


def _add_filters(p: argparse.ArgumentParser) -> None:
    p.add_argument("--since", metavar="DATE", help="runs started at or after (YYYY-MM-DD or ISO)")
    p.add_argument("--until", metavar="DATE", help="runs started before (YYYY-MM-DD or ISO)")
    p.add_argument("--product", metavar="P", help="product name as on the certificate")
    p.add_argument("--verdict", metavar="V", type=str.upper, choices=VERDICTS,
                   help="PASS, FAIL, ERROR or ABORTED")
    p.add_argument("--serial", metavar="S", help="one part's serial number")
    p.add_argument("--lot", metavar="LOT", help="one production lot (station run --lot)")
    p.add_argument("--work-order", metavar="WO",
                   help="one work order (station run --work-order)")
    p.add_argument("--db", metavar="PATH", help="results database (default: station.yaml's)")


def cmd_report(args: argparse.Namespace) -> int:
    folder = Path(args.run_folder)
    if not folder.is_dir():
        raise UserError(f"{folder} is not a run folder (no such directory); give the folder "
                        f"that holds {RECORD_FILE}")
    if not (folder / RECORD_FILE).exists() and not (folder / RAW_DATA_FILE).exists():
        # Nothing of a run here (a typo, or the runs root): an ERROR certificate would put a
        # misleading PDF in a stranger's folder. A run folder that lost one of its files
        # still gets its ERROR certificate below.
        raise UserError(f"{folder} is not a run folder (neither {RECORD_FILE} nor "
                        f"{RAW_DATA_FILE} in it); give the folder of one run")
    path = _render_checked(folder, args)
    if args.index:
        try:
            record = read_record(folder)
        except ValueError as exc:
            raise UserError(f"certificate written to {path}, but not indexed: {exc}") from exc
        _open_db(args, must_exist=False).add_run(folder, record)
    print(path)
    return 0


def _render_checked(folder: Path, args: argparse.Namespace) -> Path:
    """Verify the folder, then issue its signed certificate (station/certify.py). An altered
    record or raw file is refused, or with --unverified rendered as UNVERIFIED_FILE, marked
    on every page and neither signed nor sealed. A certificate.pdf altered alone is simply
    rendered again from the intact record."""
    # reportlab (PDF): loaded only when a report is drawn
    from reports.certificate import certificate_bytes
    from reports.pdfdoc import write_atomic
    from station.certify import issue_certificate, trusted_fingerprints

    try:
        settings = load_settings(Path(args.station) if args.station else None)
    except Exception as exc:  # ConfigError, missing file: the key is named there
        raise UserError(f"station file not loaded ({exc}); its signing: section names the key "
                        "that signs certificates; give --station FILE") from None
    result = verify_folder(folder, trusted_fingerprints(settings))
    unsealed = result.altered_files == [MANIFEST_FILE] and not (folder / MANIFEST_FILE).exists()
    if unsealed:
        print(f"warning: {folder} had no manifest (a run from before signing); it is sealed "
              "now, from the files as they are", file=sys.stderr)
    elif not result.intact and result.altered_files != [CERTIFICATE_FILE]:
        reason = "; ".join(result.problems)
        if not args.unverified:
            raise UserError(f"{folder} failed verification ({reason}); not rendered. "
                            "Give --unverified to render it marked UNVERIFIED")
        return write_atomic(folder / UNVERIFIED_FILE, certificate_bytes(folder,
                                                                           unverified=reason))
    return issue_certificate(folder, settings, origin="report")


def history_table(runs: list[RunRow]) -> list[str]:
    """The runs as text rows under a header, each column as wide as its widest cell plus
    two spaces, so no value runs into the next (product names can be long)."""
    line = any(r.lot or r.work_order for r in runs)  # the line's columns, when recorded
    header = ("started (UTC)", "serial", *(("lot", "work order") if line else ()), "product",
              "verdict", "detail")
    rows = [(r.started_utc, r.serial, *((r.lot or "-", r.work_order or "-") if line else ()),
             r.product, r.verdict,
             " ".join(filter(None, [", ".join(r.failed_measurements) or r.reason,
                                    "[sim]" if r.simulated else ""])))
            for r in runs]
    widths = [max(len(row[c]) for row in [header, *rows]) for c in range(len(header) - 1)]
    return ["  ".join(cell.ljust(w) for cell, w in zip(row[:-1], widths, strict=True))
            + ("  " + row[-1]).rstrip() for row in [header, *rows]]


def _recover(runs_dir: Path | None, db_path: Path | str | None) -> None:
    """Runs a dead station left RUNNING become ERROR (naming their last completed step) and
    are indexed before anything is listed (station/run_folder.py)."""
    # signing (pyhanko, cryptography): loaded only when used
    from station.certify import recovered_run_sealer

    settings: LoadedSettings | None = None
    try:
        settings = load_settings()
    except Exception as exc:  # no station file here: nothing to seal with
        log.info("no station settings (%s): recovered runs stay unsealed", exc)
    if runs_dir is None:
        if settings is None:
            return
        runs_dir, db_path = settings.output_folder, db_path or settings.results_db
    seal = recovered_run_sealer(settings) if settings is not None else None
    for folder in recover_results(runs_dir, db_path, seal=seal):
        print(f"marked as ERROR (the station stopped during that run): {folder}", file=sys.stderr)


def cmd_history(args: argparse.Namespace) -> int:
    if args.reindex:
        root = Path(args.reindex)
        if not root.is_dir():
            raise UserError(f"--reindex {root}: no such folder; give the folder holding the "
                            "run folders (station.yaml's output_folder)")
        _recover(root, None)  # reindexed just below
        db = _open_db(args, must_exist=False)
        added, problems = db.reindex(root)
        for p in problems:
            print(f"skipped: {p}", file=sys.stderr)
        print(f"indexed {added} run folders from {root} into {db.path}", file=sys.stderr)
    else:
        if not args.db:  # the station's own database: its runs folder is known
            _recover(None, None)
        db = _open_db(args, must_exist=True)
    try:
        runs = db.runs(**_filters(args))
    except ResultsDBError as exc:
        raise UserError(str(exc)) from exc
    if args.json:
        print(json.dumps([{
            "run_id": r.run_id, "serial": r.serial, "product": r.product,
            "verdict": r.verdict, "started_utc": r.started_utc, "reason": r.reason,
            "failed_measurements": list(r.failed_measurements), "folder": r.folder,
            "simulated": r.simulated, "lot": r.lot, "work_order": r.work_order,
            "socket": r.socket} for r in runs], indent=2))
        return 0
    if not runs:
        print("no runs match")
        return 0
    for line in history_table(runs):
        print(line)
    counts = {v: sum(r.verdict == v for r in runs) for v in VERDICTS}
    print(f"{plural(len(runs), 'run')}: " + ", ".join(f"{v} {n}" for v, n in counts.items() if n)
          + f"; {_yield_text(counts, args.verdict)}")
    return 0


def _yield_text(counts: dict[str, int], verdict_filter: str | None) -> str:
    """The yield of the listed runs; none for a list filtered by verdict (a list of FAIL
    runs has no yield to give, and "yield 0.0 %" would read as the line's)."""
    if verdict_filter:
        return f"no yield (only {verdict_filter} runs listed; drop --verdict for the yield)"
    done = counts["PASS"] + counts["FAIL"]
    return f"yield {counts['PASS'] / done * 100:.1f} %" if done else "yield n/a"


def cmd_lot_report(args: argparse.Namespace) -> int:
    # reportlab (PDF): loaded only when a report is drawn
    from reports.lot_report import render_lot_report

    db = _open_db(args, must_exist=True)
    out = Path(args.out)
    if out.suffix.lower() != ".pdf":
        raise UserError(f"--out {out}: give a file name ending in .pdf")
    issued = None
    if args.issued:
        from reports.pdfdoc import parse_utc  # reportlab (PDF): loaded only when a report is drawn

        issued = parse_utc(args.issued)
        if issued is None:
            raise UserError(f"--issued {args.issued!r}: give an ISO time, e.g. "
                            "2026-11-21T14:00:00Z (UTC when no offset is given)")
    try:
        summary = render_lot_report(db, out, issued=issued,
                                    include_simulated=args.include_simulated, **_filters(args))
    except ResultsDBError as exc:
        raise UserError(str(exc)) from exc
    y = summary.yields
    yf = f"{y.yield_fraction * 100:.1f} %" if y.yield_fraction is not None else "n/a"
    print(f"{out}: {plural(y.runs, 'run')}, yield {yf}, {plural(summary.pages, 'page')}")
    return 0


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser("report", help="render a run folder's certificate again")
    p.add_argument("run_folder", metavar="RUN_FOLDER")
    p.add_argument("--index", action="store_true", help="also (re)index it in the database")
    p.add_argument("--db", metavar="PATH", help="results database for --index")
    p.add_argument("--unverified", action="store_true",
                   help=f"render a folder that fails verification anyway, as {UNVERIFIED_FILE} "
                        "marked UNVERIFIED on every page")
    p.add_argument("--station", metavar="FILE", help="station file (default: config/station.yaml)")
    p.set_defaults(handler=cmd_report)

    p = subparsers.add_parser("history", help="list runs from the results database")
    _add_filters(p)
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--reindex", metavar="RUNS_DIR",
                   help="first (re)index every run folder under RUNS_DIR into the database")
    p.set_defaults(handler=cmd_history)

    p = subparsers.add_parser("lot-report", help="write a lot summary PDF")
    _add_filters(p)
    p.add_argument("--out", metavar="FILE.pdf", required=True, help="where to write the PDF")
    p.add_argument("--issued", metavar="TIME",
                   help="issue time printed on the report (ISO, UTC; default now); give the "
                        "original one to reproduce a report byte for byte")
    p.add_argument("--include-simulated", action="store_true",
                   help="count simulated runs too (left out by default, as on the line "
                        "dashboard; the report says how many)")
    p.set_defaults(handler=cmd_lot_report)
