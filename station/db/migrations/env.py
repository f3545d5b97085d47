"""Alembic environment: migrations run on the connection station.db.connect hands over."""

from __future__ import annotations

from alembic import context

connection = context.config.attributes.get("connection")
if connection is None:
    raise RuntimeError(
        "the results database migrates itself when opened (station.db.connect.engine_for); "
        "it is not meant to be run with the alembic command"
    )
context.configure(connection=connection, target_metadata=None, render_as_batch=True)
with context.begin_transaction():
    context.run_migrations()
