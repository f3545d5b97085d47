"""Schema 2, a line of stations: work order and lot, retests linked to a serial's first test,
the store-and-forward outbox, and the stations' last word to the central database.

Existing runs are kept: work order and lot are "" (they were not recorded), attempts and first
tests are computed from the runs already there, and every run is queued for the central
database.

Revision ID: 0002
"""

from __future__ import annotations

from datetime import UTC, datetime

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None

_NEW_RUN_COLUMNS = (
    ("work_order", sa.Text, ""),
    ("lot", sa.Text, ""),
    ("attempt", sa.Integer, "1"),
    ("first_run_id", sa.Text, ""),
    ("unit_verdict", sa.Text, ""),
    ("unit_tests", sa.Integer, "1"),
)


def upgrade() -> None:
    for name, kind, default in _NEW_RUN_COLUMNS:
        op.add_column("runs", sa.Column(name, kind, nullable=False, server_default=default))
    op.create_index("runs_unit", "runs", ["product", "serial", "started_utc"])
    op.create_index("runs_first", "runs", ["attempt", "started_utc"])
    op.create_index("runs_station", "runs", ["station_id", "started_utc"])
    op.create_index("runs_product", "runs", ["product", "started_utc"])
    op.create_index("runs_first_run", "runs", ["first_run_id"])
    # the yields' GROUP BY reads only this index, in its order (no sort over 10^5 units)
    op.create_index("runs_groups", "runs", ["attempt", "station_id", "product", "lot",
                                            "work_order", "verdict", "unit_verdict",
                                            "unit_tests", "started_utc"])
    op.create_table(
        "outbox",
        sa.Column("run_id", sa.Text, primary_key=True),
        sa.Column("version", sa.Integer, nullable=False),
        sa.Column("sent_version", sa.Integer, nullable=False, server_default="0"),
        sa.Column("queued_utc", sa.Text, nullable=False),
        sa.Column("sent_utc", sa.Text),
    )
    op.create_index("outbox_unsent", "outbox", ["sent_version", "version"])
    op.create_table(
        "stations",
        sa.Column("station_id", sa.Text, primary_key=True),
        sa.Column("last_seen_utc", sa.Text, nullable=False),
        sa.Column("state", sa.Text, nullable=False, server_default=""),
        sa.Column("pending_runs", sa.Integer, nullable=False, server_default="0"),
        sa.Column("software_version", sa.Text, nullable=False, server_default=""),
    )
    _backfill(op.get_bind())


def _backfill(con: sa.Connection) -> None:
    rows = con.execute(
        sa.text("SELECT run_id, product, serial, verdict FROM runs "
                "ORDER BY product, serial, started_utc, run_id")
    ).all()
    units: dict[tuple[str, str], list[tuple[str, str]]] = {}
    for run_id, product, serial, verdict in rows:
        units.setdefault((product, serial), []).append((run_id, verdict))
    updates = [
        {"run_id": run_id, "attempt": i + 1, "first": tests[0][0], "final": tests[-1][1],
         "n": len(tests)}
        for tests in units.values()
        for i, (run_id, _) in enumerate(tests)
    ]
    if updates:
        con.execute(
            sa.text("UPDATE runs SET attempt = :attempt, first_run_id = :first, "
                    "unit_verdict = :final, unit_tests = :n WHERE run_id = :run_id"),
            updates,
        )
        now = datetime.now(UTC).isoformat(timespec="seconds")
        con.execute(
            sa.text("INSERT INTO outbox (run_id, version, sent_version, queued_utc) "
                    "VALUES (:run_id, 1, 0, :now)"),
            [{"run_id": u["run_id"], "now": now} for u in updates],
        )


def downgrade() -> None:
    op.drop_table("stations")
    op.drop_table("outbox")
    op.drop_index("runs_groups", "runs")
    op.drop_index("runs_first_run", "runs")
    op.drop_index("runs_product", "runs")
    op.drop_index("runs_station", "runs")
    op.drop_index("runs_first", "runs")
    op.drop_index("runs_unit", "runs")
    with op.batch_alter_table("runs") as batch:
        for name, _, _ in _NEW_RUN_COLUMNS:
            batch.drop_column(name)
