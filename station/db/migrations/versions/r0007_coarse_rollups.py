"""Schema 7: the rollups at coarser grains (station/db/schema.py ROLLUP_GRAINS and
MEASUREMENT_GRAINS: per day and station, per day and lot, per hour and product, and the
measurements per day and product), kept in the same transaction as the hourly ones, filled
here from the hourly rollups (far fewer rows than the runs).

Revision ID: 0007
"""

from __future__ import annotations

from typing import Any

import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None

# the grains as this revision made them (the schema module may grow later)
RUN_GRAINS = {
    "rollup_runs_day_station": ("day_utc", "station_id", "product", "simulated"),
    "rollup_runs_day_lot": ("day_utc", "lot", "work_order", "product", "simulated"),
    "rollup_runs_hour_product": ("hour_utc", "product", "simulated"),
}
MEASUREMENT_GRAINS = {"rollup_measurements_day_product": ("day_utc", "product", "simulated")}
RUN_COUNTS = ("runs", "passed", "failed", "errored", "aborted", "running",
              "units", "unit_tests", "first_pass", "final_pass")


def _keys(keys: tuple[str, ...]) -> list[sa.Column[Any]]:
    return [sa.Column(k, sa.Integer if k == "simulated" else sa.Text, primary_key=True)
            for k in keys]


def _counted(name: str) -> sa.Column[Any]:
    return sa.Column(name, sa.Integer, nullable=False, server_default="0")


def upgrade() -> None:
    for name, keys in RUN_GRAINS.items():
        op.create_table(name, *_keys(keys), *[_counted(c) for c in RUN_COUNTS])
    for name, keys in MEASUREMENT_GRAINS.items():
        op.create_table(
            name, *_keys(keys),
            sa.Column("name", sa.Text, primary_key=True),
            sa.Column("condition", sa.Text, primary_key=True),
            sa.Column("units", sa.Text, nullable=False, server_default=""),
            _counted("n"),
            sa.Column("total", sa.Double, nullable=False, server_default="0"),
            sa.Column("total_sq", sa.Double, nullable=False, server_default="0"),
            _counted("below"), _counted("above"),
            *[sa.Column(c, sa.Double) for c in ("vmin", "vmax", "low", "high")],
        )
    # a lot's days (the key starts with the day: a lot filter would read a range of days)
    op.create_index("rollup_runs_day_lot_lot", "rollup_runs_day_lot", ["lot", "day_utc"])
    from station.db.rollups import fill_coarse

    fill_coarse(op.get_bind(), (*RUN_GRAINS, *MEASUREMENT_GRAINS))


def downgrade() -> None:
    op.drop_index("rollup_runs_day_lot_lot", "rollup_runs_day_lot")
    for name in (*MEASUREMENT_GRAINS, *RUN_GRAINS):
        op.drop_table(name)
