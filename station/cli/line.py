"""`station line`, `station sync`, `station export`: a line of stations and its database.

    station line --db URL --users FILE [--host H --tls-cert PEM --tls-key PEM]
                 [--allowed-host NAME] [--port P] [--shift-starts 6,14,22] [--offline-after S]
    station line --hash-password     (a password read from stdin -> a users-file entry)
    station sync [--db URL] [--central URL] [--wait S]
    station export --format cfx [--db URL] [--since D] [--until D] [--product P] [--out FILE]

`--db` defaults to station.yaml's results_db (line: its central_db), `--central` to its
central_db. URLs: sqlite:///PATH, postgresql+psycopg://USER@HOST/DB, or a SQLite file path.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from station import __version__
from station.db.cfx_export import export_lines
from station.db.connect import DatabaseError, shown
from station.db.sync import Sync, SyncError
from station.errors import UserError
from station.line.users import load_line_users
from station.results_db import ResultsDB, ResultsDBError, run_filters
from station.secret_input import read_secret
from station.station_file import load_settings
from station.ui.auth import hash_password
from station.ui.guard import allowed_hosts

EXPORT_FORMATS = ("cfx",)  # IPC-CFX UnitsTested, one JSON message per line


def _settings() -> Any:
    try:
        return load_settings()
    except Exception as exc:  # no station.yaml here
        raise UserError(f"no station settings ({exc}); give the database with --db") from None


def _open(url: str | None, fallback: str) -> Any:
    text = url
    if not text:
        s = _settings()
        text = str(s.central_db if fallback == "central_db" else s.results_db or "")
        if not text or text == "None":
            raise UserError(f"station.yaml has no {fallback}; give the database with --db URL")
    try:
        return ResultsDB(text)
    except ResultsDBError as exc:
        raise UserError(str(exc)) from None


def _shift_starts(text: str) -> tuple[int, ...]:
    try:
        hours = tuple(int(h) for h in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give hours such as 6,14,22") from None
    if not hours or any(not 0 <= h < 24 for h in hours) or len(set(hours)) != len(hours):
        raise argparse.ArgumentTypeError(f"{text!r}: distinct whole hours 0-23, e.g. 6,14,22")
    return hours


def _hash_line_password() -> int:
    try:
        hashed = hash_password(read_secret("password"), what="password")
    except ValueError as exc:
        raise UserError(str(exc)) from None
    print("# put this in the line users file (station line --users FILE):")
    print("users:")
    print("  - name: <user name>")
    print("    role: viewer  # or quality, engineer")
    print(f"    password_hash: '{hashed}'")
    return 0


def _line_access(args: argparse.Namespace) -> Any:
    """Users, host names and HTTPS of `station line`: refused beyond loopback without TLS."""
    # fastapi/uvicorn: loaded only when serving
    from station.line.access import LineAccess
    from station.ui.launch import refuse_clear_text, usable_tls

    if args.users is None:
        raise UserError("the dashboard needs its users: give --users FILE (see "
                        "docs/line-database.md; make password hashes with "
                        "`station line --hash-password`)")
    if (args.tls_cert is None) != (args.tls_key is None):
        raise UserError("give both --tls-cert and --tls-key (PEM files), or neither")
    tls = None
    if args.tls_cert is not None:
        tls = usable_tls(args.tls_cert, args.tls_key, ("--tls-cert", "--tls-key"))
    refuse_clear_text(args.host, tls, "the users' passwords and the session cookies",
                      "give --tls-cert and --tls-key (PEM files)")
    access = LineAccess(users=load_line_users(args.users),
                        hosts=allowed_hosts(args.host, args.allowed_host), https=tls is not None)
    return access, tls


def cmd_line(args: argparse.Namespace) -> int:
    # fastapi/uvicorn: loaded only when serving
    from station.line.app import LineOptions, create_line_app
    from station.ui.server import serve_forever

    if args.hash_password:
        return _hash_line_password()
    access, tls = _line_access(args)
    db = _open(args.db, "central_db")
    options = LineOptions(offline_after_s=args.offline_after, shift_starts_h=args.shift_starts)
    app = create_line_app(db.engine, options, access)
    scheme = "https" if tls else "http"
    print(f"line dashboard over {db.path}: {scheme}://{args.host}:{args.port}/", file=sys.stderr)
    serve_forever(app, host=args.host, port=args.port, tls=tls)
    return 0


def cmd_sync(args: argparse.Namespace) -> int:
    local = _open(args.db, "results_db")
    central_text = args.central or _settings().central_db
    if not central_text:
        raise UserError("no central database: set central_db in station.yaml or give --central")
    station_id = ""
    try:
        station_id = _settings().settings.station.id
    except UserError:
        station_id = ""
    try:
        sync = Sync(local.url, central_text, station_id=station_id, software_version=__version__)
        report = sync.push_once()
    except (SyncError, DatabaseError) as exc:
        raise UserError(str(exc)) from None
    print(f"sent {report.sent} runs to {shown(sync.central_url)}; "
          f"{report.pending} still queued", file=sys.stderr)
    return 0 if report.pending == 0 else 1


def cmd_export(args: argparse.Namespace) -> int:
    db = _open(args.db, "results_db")
    try:
        where = run_filters(args.since, args.until, args.product, None, args.serial)
        out = open(args.out, "w", encoding="utf-8") if args.out else sys.stdout  # noqa: SIM115
    except (ResultsDBError, OSError) as exc:
        raise UserError(str(exc)) from None
    n = 0
    try:
        with db.engine.connect() as con:
            for line in export_lines(con, where, source=args.source):
                out.write(line + "\n")
                n += 1
    finally:
        if out is not sys.stdout:
            out.close()
    print(f"exported {n} runs as IPC-CFX UnitsTested" + (f" to {args.out}" if args.out else ""),
          file=sys.stderr)
    return 0


def register(subparsers: Any) -> None:
    p = subparsers.add_parser("line", help="the line's dashboard in the browser")
    p.add_argument("--db", metavar="URL", help="the line's database (default: central_db)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default local)")
    p.add_argument("--port", type=int, default=8090)
    p.add_argument("--shift-starts", type=_shift_starts, default=(6, 14, 22), metavar="H,H,H",
                   help="hours (UTC) at which shifts start (default 6,14,22)")
    p.add_argument("--offline-after", type=float, default=60.0, metavar="S",
                   help="a station silent this long is shown offline (default 60 s)")
    p.add_argument("--users", type=Path, metavar="FILE",
                   help="the line users file: name, role, password_hash (required)")
    p.add_argument("--tls-cert", type=Path, metavar="PEM",
                   help="HTTPS certificate (needed beyond 127.0.0.1)")
    p.add_argument("--tls-key", type=Path, metavar="PEM", help="its private key")
    p.add_argument("--allowed-host", action="append", default=[], metavar="NAME",
                   help="a further host name the dashboard answers to (repeatable)")
    p.add_argument("--hash-password", action="store_true",
                   help="read a password (stdin) and print the users-file entry")
    p.set_defaults(handler=cmd_line)

    p = subparsers.add_parser("sync", help="push queued runs to the line's central database")
    p.add_argument("--db", metavar="URL", help="local results database (default: results_db)")
    p.add_argument("--central", metavar="URL", help="central database (default: central_db)")
    p.set_defaults(handler=cmd_sync)

    p = subparsers.add_parser("export", help="runs as a standard test-result export for an MES")
    p.add_argument("--format", choices=EXPORT_FORMATS, required=True,
                   help="cfx: IPC-CFX UnitsTested messages, one JSON per line")
    p.add_argument("--db", metavar="URL", help="results database (default: results_db)")
    for name in ("since", "until", "product", "serial"):
        p.add_argument(f"--{name}")
    p.add_argument("--source", default="", help="CFX Source handle (default: station id)")
    p.add_argument("--out", type=Path, help="file to write (default: standard output)")
    p.set_defaults(handler=cmd_export)
