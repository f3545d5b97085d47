"""Many rows into a table in a few statements, skipping rows whose primary key is there.

PostgreSQL: one `INSERT ... SELECT unnest(array), ... ON CONFLICT DO NOTHING` per chunk of
rows, each column sent as one array (a statement per row, even pipelined, costs the server
and the client about twice as much). SQLite: executemany of `INSERT ... ON CONFLICT DO
NOTHING` (in-process, no round trips to save).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import sqlalchemy as sa
from sqlalchemy.dialects import postgresql, sqlite

CHUNK = 10_000  # rows per PostgreSQL statement


def insert_new(con: sa.Connection, table: sa.Table, rows: Sequence[dict[str, Any]]) -> None:
    """Insert rows (all with the same keys), skipping any whose primary key is there."""
    if not rows:
        return
    if con.dialect.name == "postgresql":
        names = list(rows[0])
        stmt = _unnest_insert(table, names)
        for i in range(0, len(rows), CHUNK):
            con.execute(stmt, _columns(table, names, rows[i : i + CHUNK]))
    elif con.dialect.name == "sqlite":
        con.execute(sqlite.insert(table).on_conflict_do_nothing(), list(rows))
    else:
        con.execute(table.insert(), list(rows))


def _unnest_insert(table: sa.Table, names: list[str]) -> sa.Insert:
    arrays = [sa.func.unnest(sa.bindparam(n, type_=postgresql.ARRAY(table.c[n].type)))
              for n in names]
    return (postgresql.insert(table).from_select(names, sa.select(*arrays))
            .on_conflict_do_nothing())


def _columns(table: sa.Table, names: list[str], rows: Sequence[dict[str, Any]]
             ) -> dict[str, list[Any]]:
    """Each column's values as one list (floats as floats: an array has one element type)."""
    out = {n: [r[n] for r in rows] for n in names}
    for n in names:
        if isinstance(table.c[n].type, sa.Float):
            out[n] = [None if v is None else float(v) for v in out[n]]
    return out
