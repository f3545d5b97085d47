"""The line's view of a unit: each run's attempt number, the unit's first test, its final
verdict and its number of tests, recomputed over all the unit's runs after runs are written.

A batch of runs is relinked with a few statements whatever its size: the units' locks taken
at once (PostgreSQL), their tests read in chunks, and only the rows whose links changed written.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import sqlalchemy as sa

from station.db.schema import runs

LINK_COLUMNS = ("attempt", "first_run_id", "unit_verdict", "unit_tests")
_CHUNK = 500

Unit = tuple[str, str]  # (product, serial)


def relink_units(con: sa.Connection, units: Iterable[Unit]) -> None:
    """Each run of these (product, serial) units: its attempt number (1 = first test), the
    run_id of the unit's first test, the unit's final verdict (its latest test's) and its
    number of tests."""
    ordered = sorted(set(units))
    if not ordered:
        return
    if con.dialect.name == "postgresql":
        _lock_units(con, ordered)
    updates = [u for tests in _unit_tests(con, ordered).values() for u in _links(tests)]
    if updates:
        con.execute(
            runs.update()
            .where(runs.c.run_id == sa.bindparam("rid"))
            .values(attempt=sa.bindparam("a"), first_run_id=sa.bindparam("f"),
                    unit_verdict=sa.bindparam("v"), unit_tests=sa.bindparam("n")),
            updates,
        )


def _lock_units(con: sa.Connection, ordered: list[Unit]) -> None:
    """Two stations delivering tests of one serial at once: one relinks after the other.
    The locks are taken in sorted order (volatile functions run after ORDER BY), so two
    batches cannot deadlock; SQLite serialises writers anyway."""
    keys = [f"{product}\x1f{serial}" for product, serial in ordered]
    con.execute(sa.text(
        "SELECT pg_advisory_xact_lock(hashtext(u.k)) "
        "FROM unnest(CAST(:keys AS text[])) WITH ORDINALITY AS u(k, i) ORDER BY u.i"
    ), {"keys": keys}).all()


def _unit_tests(con: sa.Connection, ordered: list[Unit]) -> dict[Unit, list[Any]]:
    """Each unit's runs in test order (started, then run_id, in the database's order)."""
    wanted = set(ordered)
    out: dict[Unit, list[Any]] = {u: [] for u in ordered}
    serials = sorted({serial for _, serial in ordered})
    for i in range(0, len(serials), _CHUNK):
        query = (
            sa.select(runs.c.product, runs.c.serial, runs.c.run_id, runs.c.verdict,
                      *[runs.c[c] for c in LINK_COLUMNS])
            .where(runs.c.serial.in_(serials[i : i + _CHUNK]))
            .order_by(runs.c.product, runs.c.serial, runs.c.started_utc, runs.c.run_id)
        )
        for row in con.execute(query):
            if (row.product, row.serial) in wanted:
                out[(row.product, row.serial)].append(row)
    return out


def _links(tests: Sequence[Any]) -> list[dict[str, Any]]:
    """The link updates of one unit's tests, only for the rows that differ."""
    if not tests:
        return []
    first, final = tests[0].run_id, tests[-1].verdict
    return [
        {"rid": t.run_id, "a": i + 1, "f": first, "v": final, "n": len(tests)}
        for i, t in enumerate(tests)
        if (t.attempt, t.first_run_id, t.unit_verdict, t.unit_tests)
        != (i + 1, first, final, len(tests))
    ]
