"""Opening a results database by URL: engines shared per URL, migrations run on first open.

`results_db:` and `central_db:` in station.yaml, and `--db` on the command line, take a
SQLAlchemy URL (`sqlite:///runs/results.sqlite`, `postgresql+psycopg://user@host/line`) or a
bare path, which means a SQLite file. Relative SQLite paths are relative to a base folder
(station.yaml's folder, or the working directory on the command line).
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path
from typing import Any

import sqlalchemy as sa
from sqlalchemy.engine import Engine, make_url
from sqlalchemy.exc import ArgumentError, SQLAlchemyError

log = logging.getLogger(__name__)

MIGRATIONS = Path(__file__).resolve().parent / "migrations"
HEAD_REVISION = "0007"

_engines: dict[str, Engine] = {}
_migrated: set[str] = set()
_lock = threading.Lock()


class DatabaseError(ValueError):
    """The database cannot be opened or written; the message says what to do."""


def is_url(text: str | Path) -> bool:
    return isinstance(text, str) and "://" in text


def database_url(text: str | Path, base: Path | None = None) -> str:
    """A URL for a bare path (SQLite) or a URL; relative SQLite paths resolved against base."""
    if not is_url(text):
        path = Path(text).expanduser()
        if not path.is_absolute():
            path = (base or Path.cwd()) / path
        return f"sqlite:///{path.resolve()}"
    try:
        url = make_url(str(text))
    except (ArgumentError, ValueError) as exc:
        raise DatabaseError(
            f"database URL {text!r} not understood ({exc}); give sqlite:///PATH, "
            "postgresql+psycopg://USER@HOST/DB or a file path"
        ) from None
    if url.get_backend_name() == "sqlite" and url.database and url.database != ":memory:":
        path = Path(url.database).expanduser()
        if not path.is_absolute():
            path = (base or Path.cwd()) / path
        return f"sqlite:///{path.resolve()}"
    return str(text)


def sqlite_path(url: str) -> Path | None:
    """The file of a sqlite:/// URL, None for any other database."""
    u = make_url(url)
    if u.get_backend_name() == "sqlite" and u.database and u.database != ":memory:":
        return Path(u.database)
    return None


def shown(url: str) -> str:
    """The URL without its password, for messages and logs."""
    try:
        return make_url(url).render_as_string(hide_password=True)
    except (ArgumentError, ValueError):  # a bare path
        return url


def _sqlite_pragmas(dbapi_con: Any, _record: Any) -> None:
    cur = dbapi_con.cursor()
    cur.execute("PRAGMA foreign_keys = ON")
    cur.close()


def engine_for(url: str) -> Engine:
    """The process's engine for a URL (created once), with the schema migrated to head."""
    with _lock:
        engine = _engines.get(url)
        if engine is None:
            engine = _create(url)
            _engines[url] = engine
        if url not in _migrated:
            _migrate(engine, url)
            _migrated.add(url)
    return engine


def _create(url: str) -> Engine:
    path = sqlite_path(url)
    try:
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            engine = sa.create_engine(url, connect_args={"timeout": 15.0})
            sa.event.listen(engine, "connect", _sqlite_pragmas)
            return engine
        return sa.create_engine(url, pool_pre_ping=True, connect_args=_connect_args(url))
    except (SQLAlchemyError, OSError, ImportError) as exc:
        raise DatabaseError(
            f"{shown(url)}: cannot open the results database ({exc}); check the URL or path "
            "and its permissions"
        ) from None


def _connect_args(url: str) -> dict[str, Any]:
    if make_url(url).get_backend_name() == "postgresql":
        return {"connect_timeout": 5}
    return {}


def _migrate(engine: Engine, url: str) -> None:
    """Bring the schema to head with alembic (nothing to do when it is there already)."""
    try:
        with engine.connect() as con:
            if _current_revision(con) == HEAD_REVISION:
                return
        from alembic import command
        from alembic.config import Config

        cfg = Config()
        cfg.set_main_option("script_location", str(MIGRATIONS))
        with engine.begin() as con:
            cfg.attributes["connection"] = con
            command.upgrade(cfg, "head")
        log.info("results database %s migrated to schema %s", shown(url), HEAD_REVISION)
    except (SQLAlchemyError, OSError) as exc:
        raise DatabaseError(
            f"{shown(url)}: cannot open the results database ({exc}); check the URL or path, "
            "its permissions, and that the database server is running"
        ) from None


def _current_revision(con: sa.Connection) -> str | None:
    if not sa.inspect(con).has_table("alembic_version"):
        return None
    return con.execute(sa.text("SELECT version_num FROM alembic_version")).scalar()


def dispose_all() -> None:
    """Close every pooled connection (tests, and before a forked process uses the database)."""
    with _lock:
        for engine in _engines.values():
            engine.dispose()
        _engines.clear()
        _migrated.clear()
