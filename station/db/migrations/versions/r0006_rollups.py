"""Schema 6: rollups kept up to date as runs arrive (station/db/rollups.py), filled here from
the runs already there; indexes for the dashboard's bounded reads and the outbox's queue.

rollup_runs: per hour (UTC), station, product, lot, work order and simulated flag, the runs
by verdict and the yields' units. rollup_measurements: per the same key, each measurement of
the first tests summed (n, sum, sum of squares, extremes, limits, values outside them).

Revision ID: 0006
"""

from __future__ import annotations

from typing import Any

import sqlalchemy as sa
from alembic import op

revision = "0006"
down_revision = "0005"
branch_labels = None
depends_on = None


def _key_columns() -> list[sa.Column[Any]]:
    return [
        sa.Column("hour_utc", sa.Text, primary_key=True),
        sa.Column("station_id", sa.Text, primary_key=True),
        sa.Column("product", sa.Text, primary_key=True),
        sa.Column("lot", sa.Text, primary_key=True),
        sa.Column("work_order", sa.Text, primary_key=True),
        sa.Column("simulated", sa.Integer, primary_key=True),
    ]


def _counted(name: str) -> sa.Column[Any]:
    return sa.Column(name, sa.Integer, nullable=False, server_default="0")


def upgrade() -> None:
    op.create_table(
        "rollup_runs", *_key_columns(),
        *[_counted(c) for c in ("runs", "passed", "failed", "errored", "aborted", "running",
                                "units", "unit_tests", "first_pass", "final_pass")],
    )
    op.create_table(
        "rollup_measurements", *_key_columns(),
        sa.Column("name", sa.Text, primary_key=True),
        sa.Column("condition", sa.Text, primary_key=True),
        sa.Column("units", sa.Text, nullable=False, server_default=""),
        _counted("n"),
        sa.Column("total", sa.Double, nullable=False, server_default="0"),
        sa.Column("total_sq", sa.Double, nullable=False, server_default="0"),
        _counted("below"), _counted("above"),
        *[sa.Column(c, sa.Double) for c in ("vmin", "vmax", "low", "high")],
    )
    # a lot's hours (the rollups' key starts with the hour: the other filters read a range)
    op.create_index("rollup_runs_lot", "rollup_runs", ["lot", "hour_utc"])
    op.create_index("rollup_measurements_lot", "rollup_measurements", ["lot", "hour_utc"])
    # the drill-down's latest runs of a lot, as the station and product indexes do for theirs
    op.create_index("runs_lot", "runs", ["lot", "started_utc"])
    # the sync's queue: only what is not yet sent, in the order it is sent
    op.create_index("outbox_queue", "outbox", ["queued_utc", "run_id"],
                    postgresql_where=sa.text("sent_version < version"),
                    sqlite_where=sa.text("sent_version < version"))
    from station.db.rollups import add_hourly

    add_hourly(op.get_bind())


def downgrade() -> None:
    op.drop_index("outbox_queue", "outbox")
    op.drop_index("runs_lot", "runs")
    op.drop_index("rollup_measurements_lot", "rollup_measurements")
    op.drop_index("rollup_runs_lot", "rollup_runs")
    op.drop_table("rollup_measurements")
    op.drop_table("rollup_runs")
