"""Schema 4, three-axis parts: the runs' `axes` (1 for every run before) and one row per
element of a three-axis calibration (bias vector, correction matrix, g-sensitivity and the
per-axis temperature and supply coefficients, each with its k = 2 uncertainty).

Existing runs are kept as they are; they read as single-axis runs with no elements.

Revision ID: 0004
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0004"
down_revision = "0003"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column("runs", sa.Column("axes", sa.Integer, nullable=False, server_default="1"))
    op.create_table(
        "calibration_elements",
        sa.Column("run_id", sa.Text, sa.ForeignKey("runs.run_id", ondelete="CASCADE"),
                  primary_key=True),
        sa.Column("seq", sa.Integer, primary_key=True),
        sa.Column("quantity", sa.Text, nullable=False),
        sa.Column("axis", sa.Text, nullable=False),
        sa.Column("column_axis", sa.Text),
        sa.Column("value", sa.Double),
        sa.Column("uncertainty_k2", sa.Double),
    )
    op.create_index("calibration_elements_quantity", "calibration_elements",
                    ["quantity", "axis", "column_axis"])


def downgrade() -> None:
    op.drop_index("calibration_elements_quantity", "calibration_elements")
    op.drop_table("calibration_elements")
    with op.batch_alter_table("runs") as batch:
        batch.drop_column("axes")
