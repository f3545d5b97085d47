"""The line's view of a unit: each run's attempt number, the unit's first test, its final
verdict and its number of tests, recomputed over all the unit's runs when runs are written.

A batch of runs is linked with a few statements whatever its size: the units' locks taken
at once (PostgreSQL), their tests read in chunks, new rows inserted with their links
already set (with_links), and afterwards only the rows whose links changed updated
(relink_units: the database's order of the tests is the one that counts).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import sqlalchemy as sa

from station.db.schema import runs

LINK_COLUMNS = ("attempt", "first_run_id", "unit_verdict", "unit_tests")
_CHUNK = 500

Unit = tuple[str, str]  # (product, serial)
Links = tuple[int, str, str, int]  # attempt, first_run_id, unit_verdict, unit_tests


def relink_units(con: sa.Connection, units: Iterable[Unit]) -> None:
    """Each run of these (product, serial) units: its attempt number (1 = first test), the
    run_id of the unit's first test, the unit's final verdict (its latest test's) and its
    number of tests."""
    ordered = sorted(set(units))
    if not ordered:
        return
    lock_units(con, ordered)
    updates = [
        {"rid": t["run_id"], "a": a, "f": f, "v": v, "n": n}
        for tests in _unit_tests(con, ordered).values()
        for t, (a, f, v, n) in zip(tests, _links(tests), strict=True)
        if tuple(t[c] for c in LINK_COLUMNS) != (a, f, v, n)
    ]
    if updates:
        con.execute(
            runs.update()
            .where(runs.c.run_id == sa.bindparam("rid"))
            .values(attempt=sa.bindparam("a"), first_run_id=sa.bindparam("f"),
                    unit_verdict=sa.bindparam("v"), unit_tests=sa.bindparam("n")),
            updates,
        )


def with_links(con: sa.Connection, rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Runs about to be inserted, with the links they will have among their units' tests
    in the database (tests ordered here by started_utc, run_id; relink_units afterwards
    corrects any run the database orders otherwise, and the units' earlier tests). The
    caller holds the units' locks (lock_units)."""
    ordered = sorted({(r["product"], r["serial"]) for r in rows})
    new = {r["run_id"] for r in rows}
    tests = {unit: [t for t in unit_tests if t["run_id"] not in new]
             for unit, unit_tests in _unit_tests(con, ordered).items()}
    for r in rows:
        tests[(r["product"], r["serial"])].append(r)
    links: dict[str, Links] = {}
    for unit_tests in tests.values():
        unit_tests.sort(key=lambda t: (t["started_utc"], t["run_id"]))
        links.update(zip([t["run_id"] for t in unit_tests], _links(unit_tests), strict=True))
    return [{**r, **dict(zip(LINK_COLUMNS, links[r["run_id"]], strict=True))} for r in rows]


def lock_units(con: sa.Connection, ordered: Sequence[Unit]) -> None:
    """Two stations delivering tests of one serial at once: one links after the other.
    The locks are taken in sorted order (volatile functions run after ORDER BY), so two
    batches cannot deadlock; SQLite serialises writers anyway. Taken again, a lock held by
    the transaction costs nothing."""
    if con.dialect.name != "postgresql":
        return
    keys = [f"{product}\x1f{serial}" for product, serial in ordered]
    con.execute(sa.text(
        "SELECT pg_advisory_xact_lock(hashtext(u.k)) "
        "FROM unnest(CAST(:keys AS text[])) WITH ORDINALITY AS u(k, i) ORDER BY u.i"
    ), {"keys": keys}).all()


def _unit_tests(con: sa.Connection, ordered: list[Unit]) -> dict[Unit, list[Any]]:
    """Each unit's runs in the database, in test order (started, then run_id)."""
    wanted = set(ordered)
    out: dict[Unit, list[Any]] = {u: [] for u in ordered}
    serials = sorted({serial for _, serial in ordered})
    for i in range(0, len(serials), _CHUNK):
        query = (
            sa.select(runs.c.product, runs.c.serial, runs.c.run_id, runs.c.verdict,
                      runs.c.started_utc, *[runs.c[c] for c in LINK_COLUMNS])
            .where(runs.c.serial.in_(serials[i : i + _CHUNK]))
            .order_by(runs.c.product, runs.c.serial, runs.c.started_utc, runs.c.run_id)
        )
        for row in con.execute(query).mappings():
            if (row["product"], row["serial"]) in wanted:
                out[(row["product"], row["serial"])].append(row)
    return out


def _links(tests: Sequence[Any]) -> list[Links]:
    """The links of one unit's tests, in test order."""
    first, final = tests[0]["run_id"], tests[-1]["verdict"]
    return [(i + 1, first, final, len(tests)) for i in range(len(tests))]
