"""Schema 1: the runs and measurements of the hand-written SQLite index (kept as it was).

A results.sqlite made before alembic already has these tables (PRAGMA user_version 1); this
revision then creates nothing and only records that the file is at schema 1.

Revision ID: 0001
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None

_CAL_KEYS = (
    "bias_dps",
    "bias_temp_coeff_dps_per_c",
    "bias_supply_coeff_dps_per_v",
    "scale",
    "scale_temp_coeff_per_c",
    "scale_supply_coeff_per_v",
)


def upgrade() -> None:
    inspector = sa.inspect(op.get_bind())
    if not inspector.has_table("runs"):
        op.create_table(
            "runs",
            sa.Column("run_id", sa.Text, primary_key=True),
            sa.Column("serial", sa.Text, nullable=False),
            sa.Column("product", sa.Text, nullable=False),
            sa.Column("verdict", sa.Text, nullable=False),
            sa.Column("reason", sa.Text, nullable=False, server_default=""),
            sa.Column("failed_measurements", sa.Text, nullable=False, server_default="[]"),
            sa.Column("simulated", sa.Integer, nullable=False, server_default="0"),
            sa.Column("started_utc", sa.Text, nullable=False),
            sa.Column("finished_utc", sa.Text),
            *[
                sa.Column(name, sa.Text, nullable=False, server_default="")
                for name in (
                    "station_id", "operator", "software_version", "procedure_name",
                    "procedure_sha256", "product_sha256", "raw_sha256",
                )
            ],
            sa.Column("folder", sa.Text, nullable=False),
            *[
                c
                for k in _CAL_KEYS
                for c in (sa.Column(f"cal_{k}", sa.Double), sa.Column(f"cal_{k}_u", sa.Double))
            ],
        )
        op.create_index("runs_started", "runs", ["started_utc"])
        op.create_index("runs_serial", "runs", ["serial"])
    if not inspector.has_table("measurements"):
        op.create_table(
            "measurements",
            sa.Column(
                "run_id", sa.Text, sa.ForeignKey("runs.run_id", ondelete="CASCADE"),
                primary_key=True,
            ),
            sa.Column("seq", sa.Integer, primary_key=True),
            sa.Column("name", sa.Text, nullable=False),
            sa.Column("condition", sa.Text),
            sa.Column("value", sa.Double),
            sa.Column("units", sa.Text, nullable=False, server_default=""),
            sa.Column("low", sa.Double),
            sa.Column("high", sa.Double),
            sa.Column("marginal_low", sa.Double),
            sa.Column("marginal_high", sa.Double),
            sa.Column("outcome", sa.Text, nullable=False),
            sa.Column("uncertainty_k2", sa.Double),
        )
        op.create_index("measurements_name", "measurements", ["name"])


def downgrade() -> None:
    op.drop_table("measurements")
    op.drop_table("runs")
