"""Schema 5: the socket each run's part sat in (the review screen's Socket column).

Runs indexed before keep 0, shown as not recorded; `station history --reindex` fills it in
from their records (record.json `dut.socket`).

Revision ID: 0005
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column("runs", sa.Column("socket", sa.Integer, nullable=False, server_default="0"))


def downgrade() -> None:
    with op.batch_alter_table("runs") as batch:
        batch.drop_column("socket")
