"""Alembic migrations of the results database (run on open by station.db.connect)."""
